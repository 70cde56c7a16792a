"""Read a mission's recording (mission.mcap) and print its channels, their message counts and the verdict.

`skynet mission` (and `skynet gcs --out DIR`) records everything on the fleet's keys, and the
ground station's own entries, in DIR/mission.mcap; `load_record` rebuilds the mission's record from
it alone, as `skynet report` does (services/recording/load.py). No network needed::

    python examples/read_mcap.py reports/mission-20260101T120000Z

The reader is bounded: a damaged or crafted file is refused in one line (exit status 1).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from protocol.textsafe import printable
from services.recording.load import load_record
from services.recording.mcap_log import read


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", help="a mission's report folder, or its mission.mcap")
    args = parser.parse_args(argv)
    path = Path(args.path)
    path = path / "mission.mcap" if path.is_dir() else path
    try:
        channels = Counter(item.topic for item in read(path))
        record, readout = load_record(path)
    except (ValueError, OSError) as exc:  # McapReadError, NotAMissionLog, a missing file: one line
        parser.exit(1, f"{parser.prog}: error: {exc}\n")
    except KeyboardInterrupt:
        return 1
    for topic, n in sorted(channels.items()):
        print(f"{n:8d}  {printable(topic)}")  # text from a file is data: no terminal escapes
    print(f"{sum(channels.values())} messages on {len(channels)} channels; fleet {printable(record.fleet)}, "
          f"{len(record.states)} states, {len(record.defects)} defect reports, {len(record.commands)} commands")
    for note in record.recording_errors:
        print(f"note: {printable(note)}")
    print("verdict: success" if record.success else "verdict: failed: " + printable("; ".join(record.failures)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
