"""Cost of the imagery framing per frame: RTP pack, unpack, and jitter-buffer push.

For each payload size (default 200 KB, a compressed 12 MP inspection JPEG is of that order;
also 2 KB to show the fixed per-frame cost), times, over many frames of one stream:

- ``sender.frame``  : RtpSender.frame (header + one copy of the payload into the packet)
- ``unpack``        : unpack_frame (zero-copy view of the payload)
- ``push``          : JitterBuffer.push of an in-order frame (released at once)
- ``push_reorder``  : JitterBuffer.push with every other pair of frames swapped
- ``round trip``    : frame + unpack + push together, as the link would see it

and prints ns/frame (median of repeats) and the equivalent frame rate, then writes JSON.

    .venv/bin/python bench/rtp.py [--quick] [--out bench/results/rtp.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.jitter import JitterBuffer  # noqa: E402
from protocol.rtp import RtpHeader, RtpSender, pack_frame, ssrc_for, unpack_frame  # noqa: E402


def time_per_frame(fn, n: int, repeats: int) -> float:
    """Median over ``repeats`` of the mean ns per call of ``fn(i)`` for i in range(n)."""
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        for i in range(n):
            fn(i)
        samples.append((time.perf_counter_ns() - t0) / n)
    return statistics.median(samples)


def bench_size(size: int, n: int, repeats: int) -> list[dict]:
    payload = np.random.default_rng(0).integers(0, 256, size=size, dtype=np.uint8).tobytes()
    t_frame = 1 / 30
    rows = []

    sender = RtpSender(ssrc_for(1), initial_seq=65000)
    rows.append(("sender.frame", time_per_frame(lambda i: sender.frame(payload, i * t_frame), n, repeats)))

    packets = [RtpSender(ssrc_for(1), initial_seq=65000).frame(payload, 0.0)] * n
    rows.append(("unpack", time_per_frame(lambda i: unpack_frame(packets[i]), n, repeats)))

    # one payload view shared by all headers: the push cost does not depend on the payload,
    # and n * repeats distinct 200 KB packets would not fit in memory
    view = unpack_frame(pack_frame(RtpHeader(0, 0, 1), payload))[1]
    parsed = [(RtpHeader((65000 + k) % 65536, (3000 * k) % 2**32, ssrc_for(1)), view) for k in range(n * repeats)]
    jb = JitterBuffer(capacity=64, playout_delay_s=0.1)
    offset = [0]

    def push(i: int) -> None:
        k = offset[0] + i
        h, p = parsed[k]
        jb.push(h, p, k * t_frame)

    def push_all(i: int) -> None:
        push(i)
        if i == n - 1:
            offset[0] += n

    rows.append(("push", time_per_frame(push_all, n, repeats)))

    swapped = list(range(n * repeats))
    for k in range(0, len(swapped) - 1, 4):  # swap pairs (k, k+1) every 4 frames
        swapped[k], swapped[k + 1] = swapped[k + 1], swapped[k]
    jb2 = JitterBuffer(capacity=64, playout_delay_s=0.1)
    offset2 = [0]

    def push_reorder(i: int) -> None:
        k = offset2[0] + i
        h, p = parsed[swapped[k]]
        jb2.push(h, p, k * t_frame)
        if i == n - 1:
            offset2[0] += n

    rows.append(("push_reorder", time_per_frame(push_reorder, n, repeats)))
    assert jb2.stats().lost == 0 and jb2.stats().reordered > 0, jb2.stats()

    snd = RtpSender(ssrc_for(1), initial_seq=65000)
    jb3 = JitterBuffer(capacity=64, playout_delay_s=0.1)
    count = [0]

    def round_trip(i: int) -> None:
        k = count[0]
        count[0] += 1
        h, p = unpack_frame(snd.frame(payload, k * t_frame))
        jb3.push(h, p, k * t_frame)

    rows.append(("round trip", time_per_frame(round_trip, n, repeats)))
    assert jb3.stats().delivered == count[0] and jb3.stats().lost == 0

    # copy floor: what one memcpy of the payload costs (pack_frame does exactly one)
    rows.append(("(bytes copy)", time_per_frame(lambda i: bytearray(payload), n, repeats)))
    return [{"payload_bytes": size, "operation": op, "ns_per_frame": ns, "frames_per_s": 1e9 / ns} for op, ns in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[200_000, 2_000])
    parser.add_argument("--frames", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="200 frames x 3 repeats")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "rtp.json"))
    args = parser.parse_args()
    if args.quick:
        args.frames, args.repeats = 200, 3
    if any(s < 0 for s in args.sizes) or args.frames < 1 or args.repeats < 1:
        parser.error("sizes must be >= 0, frames and repeats >= 1")

    rows = [r for size in args.sizes for r in bench_size(size, args.frames, args.repeats)]
    print(f"{'payload':>9}  {'operation':<14} {'ns/frame':>10} {'frames/s':>12}")
    for r in rows:
        print(f"{r['payload_bytes']:>9}  {r['operation']:<14} {r['ns_per_frame']:>10.0f} {r['frames_per_s']:>12.0f}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "rows": rows,
        "frames": args.frames,
        "repeats": args.repeats,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
