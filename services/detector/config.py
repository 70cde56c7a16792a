"""The detector service's typed configuration (``skynet detector``)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, PlainSerializer

from protocol.bus import BusMode, BusOptions
from protocol.cliconfig import Cli

from .partition import MAX_UAV, Partition
from .pool import CONTEXTS

#: the detection methods of :data:`services.detector.detect.METHODS`, named here so that the config (which the
#: launcher builds the detector's command line from) loads no OpenCV
Method = Literal["it", "it+", "it+bh", "it+r", "it-paper", "itth", "learned", "otsu", "sauvola", "sdd", "ve"]
#: the real-time report's pixel budget, megapixels (``--detect-max-mp``): a 12 MP capture is
#: detected on its 1/4 decode, 1000 x 750. That samples the wall at 4 x its ground sampling distance
#: (5.0 mm at the paper's 4.78 m), finer than the 640 x 480 frames (7.8 mm) every inspection test passes on; the
#: 1/2 decode (3 MP) takes 3-5 times as long and is above the defect list's pixel budget (detect.defects_of works
#: on blocks there), so a crack whose block box is not its mask's box falls back to the bounding-box diagonal
#: (3.7 m for a 5.9 m crack on one such frame). The kept frame (the deliverable's input) stays full size.
DETECT_MAX_MP = 1.0

#: frames waiting for a worker before the oldest is dropped. Capture frames are what coverage counts,
#: and recovery hands them over in bursts (every camera's cache, up to 32 frames each, after an outage
#: or a gateway restart), so the queue holds such a burst (~50 kB a frame: a few MB); the Zenoh
#: callback never waits for it either way.
QUEUE_FRAMES = 128


def _partition(text: Any) -> Any:
    return Partition.parse(text) if isinstance(text, str) else text


#: ``K/N``: one of N detector instances
PartitionArg = Annotated[Partition, BeforeValidator(_partition), PlainSerializer(str)]


class DetectorConfig(BusOptions):
    """The options of the detector RCU."""

    mode: BusMode = "client"
    method: Method = Field(default="it+r", description="detection method")
    workers: int = Field(default=2, ge=1, le=64, description="detection worker processes")
    start_method: Literal[CONTEXTS] = Field(  # type: ignore[valid-type]
        default="spawn", description="how the worker processes start (never fork: Zenoh's threads)")
    partition: Annotated[PartitionArg, Cli(metavar="K/N")] = Field(
        default=Partition(), description="analyse only the cameras of the UAVs with id %% N == K (one of N "
                                         "instances, named detector-K); 0/1: every camera")
    max_uav: Annotated[int, Cli(flag="--uavs", metavar="N")] = Field(
        default=MAX_UAV, ge=1, le=MAX_UAV,
        description="UAVs 1..N: the fleet a partition subscribes to (one camera key per owned UAV)")
    queue: int = Field(default=QUEUE_FRAMES, ge=1, le=100_000,
                       description="frames waiting for a worker before the oldest drop")
    playout_delay: Annotated[float, Cli(flag="--playout-delay-s", metavar="S")] = Field(default=0.05, ge=0.0, le=10.0, description="wait for a missing frame, s")
    no_recovery: bool = Field(default=False, description="do not ask the cameras' caches for lost capture frames "
                                                         "(plain best-effort)")
    detect_max_mp: Annotated[float, Cli(metavar="MP")] = Field(
        default=DETECT_MAX_MP, ge=0.0,
        description="detect on a 1/2, 1/4 or 1/8 decode of frames above MP megapixels (a 12 MP capture at 0.75 MP "
                    "by default; the kept frame stays full size); 0: always full size")
    save_frames: Annotated[str | None, Cli(metavar="DIR")] = Field(
        default=None, description="keep every analysed capture with its pose in DIR (input of the inspection "
                                  "deliverable)")
