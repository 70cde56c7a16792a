"""bench/bus_ab.py's summary: per topology and size, the median over runs of each figure."""

from __future__ import annotations

import importlib.util
from pathlib import Path

_spec = importlib.util.spec_from_file_location("bench_bus_ab", Path(__file__).resolve().parents[2] / "bench" / "bus_ab.py")
assert _spec is not None and _spec.loader is not None
bus_ab = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bus_ab)


def _run(rtt: float, share: float) -> dict:
    side = {"rtt_median_us": rtt, "rtt_p99_us": 10 * rtt, "msgs_per_s": 1000.0}
    return {"rows": [{"topology": "p2p", "size": 200, "raw": side, "bus": {**side, "rtt_median_us": 2 * rtt},
                      "latency_ratio": 2.0, "p99_ratio": 1.0, "throughput_share": share}]}


def test_the_summary_takes_the_median_of_the_runs():
    (row,) = bus_ab.summary([_run(100.0, 0.5), _run(300.0, 0.9), _run(200.0, 0.1)])
    assert (row["topology"], row["size"]) == ("p2p", 200)
    assert row["raw_rtt_median_us"] == 200.0 and row["bus_rtt_median_us"] == 400.0
    assert row["throughput_share"] == 0.5 and row["latency_ratio"] == 2.0
