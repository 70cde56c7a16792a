"""The detector service's typed configuration (``skynet detector``)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, PlainSerializer

from protocol.bus import BusMode, BusOptions
from protocol.cliconfig import Cli

from .detect import METHODS
from .partition import MAX_UAV, Partition
from .pipeline import DETECT_MAX_MP
from .pool import CONTEXTS

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
    method: Literal[tuple(sorted(METHODS))] = Field(default="it+r", description="detection method")  # type: ignore[valid-type]
    workers: int = Field(default=2, ge=1, le=64, description="detection worker processes")
    start_method: Literal[CONTEXTS] = Field(  # type: ignore[valid-type]
        default="spawn", description="how the worker processes start (never fork: Zenoh's threads)")
    partition: Annotated[PartitionArg, Cli(metavar="K/N")] = Field(
        default=Partition(), description="analyse only the cameras of the UAVs with id %% N == K (one of N "
                                         "instances, named detector-K); 0/1: every camera")
    max_uav: int = Field(default=MAX_UAV, ge=1, le=MAX_UAV,
                         description="highest UAV id a partition subscribes to (one camera key per owned UAV)")
    queue: int = Field(default=QUEUE_FRAMES, ge=1, le=100_000,
                       description="frames waiting for a worker before the oldest drop")
    playout_delay: float = Field(default=0.05, ge=0.0, le=10.0, description="wait for a missing frame, s")
    no_recovery: bool = Field(default=False, description="do not ask the cameras' caches for lost capture frames "
                                                         "(plain best-effort)")
    detect_max_mp: Annotated[float, Cli(metavar="MP")] = Field(
        default=DETECT_MAX_MP, ge=0.0,
        description="detect on a 1/2, 1/4 or 1/8 decode of frames above MP megapixels (a 12 MP capture at 0.75 MP "
                    "by default; the kept frame stays full size); 0: always full size")
    save_frames: Annotated[str | None, Cli(metavar="DIR")] = Field(
        default=None, description="keep every analysed capture with its pose in DIR (input of the inspection "
                                  "deliverable)")
