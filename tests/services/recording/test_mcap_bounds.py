"""A crafted MCAP file (one zstd chunk of 33 KB declaring 1 GiB uncompressed) is refused by every reader of
services.recording before it is decompressed: ``skynet replay`` in its own process ends with a one-line
error and a small peak memory, ``read`` and the loader raise a ValueError naming the chunk."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message, Schema
from mcap.writer import MCAP0_MAGIC

from services.recording.load import load_record
from services.recording.mcap_log import MAX_CHUNK_BYTES, McapLog, McapReadError, read
from tests.conftest import ROOT

GIB = 1 << 30


def _bomb(size: int = GIB) -> bytes:
    """``size`` zero bytes as one zstd frame that says so (a few tens of KB), made in 1 MiB steps."""
    cobj = zstandard.ZstdCompressor(level=3).compressobj(size=size)
    block = bytes(1 << 20)
    out = [cobj.compress(block) for _ in range(size >> 20)]
    return b"".join(out) + cobj.flush()


def crafted_mcap(path: Path, indexed: bool, declared: int = GIB, data: bytes | None = None) -> Path:
    """An MCAP file whose one chunk holds ``data`` (default: the 1 GiB bomb) and declares ``declared`` bytes;
    ``indexed``: with a summary section whose chunk index points at it (as a recorder's file has)."""
    data = _bomb() if data is None else data
    b = RecordBuilder()
    b.write(MCAP0_MAGIC)
    Header(profile="", library="crafted").write(b)
    Schema(id=1, name="skynet.Event", encoding="jsonschema", data=b"{}").write(b)
    Channel(id=1, topic="skynet/demo/uav/1/event", message_encoding="json", schema_id=1, metadata={}).write(b)
    chunk_at = b.count
    Chunk(compression="zstd", data=data, message_start_time=0, message_end_time=1, uncompressed_crc=0,
          uncompressed_size=declared).write(b)
    chunk_len = b.count - chunk_at
    DataEnd(data_section_crc=0).write(b)
    summary = 0
    if indexed:
        summary = b.count
        Schema(id=1, name="skynet.Event", encoding="jsonschema", data=b"{}").write(b)
        Channel(id=1, topic="skynet/demo/uav/1/event", message_encoding="json", schema_id=1, metadata={}).write(b)
        ChunkIndex(message_start_time=0, message_end_time=1, chunk_start_offset=chunk_at, chunk_length=chunk_len,
                   message_index_offsets={}, message_index_length=0, compression="zstd",
                   compressed_size=len(data), uncompressed_size=min(declared, 1 << 20)).write(b)
    Footer(summary_start=summary, summary_offset_start=0, summary_crc=0).write(b)
    b.write(MCAP0_MAGIC)
    path.write_bytes(b.end())
    return path


@pytest.fixture(scope="module")
def bomb() -> bytes:
    return _bomb()


@pytest.mark.parametrize("indexed", [False, True], ids=["linear", "indexed"])
def test_every_reader_refuses_a_chunk_declaring_1_gib(tmp_path, bomb, indexed):
    path = crafted_mcap(tmp_path / "bomb.mcap", indexed, data=bomb)
    assert path.stat().st_size < 64_000
    with pytest.raises(McapReadError, match=r"declares 1073741824 bytes uncompressed, more than the \d+ bytes"):
        list(read(path))
    for reader in (load_record,):  # the one loader of the mission's record
        with pytest.raises(ValueError, match="1073741824"):
            reader(path)


def test_a_chunk_that_hides_its_size_from_its_record_is_refused(tmp_path, bomb):
    """The chunk record says 1 KiB, its zstd frame 1 GiB (zstd would allocate the frame's size)."""
    path = crafted_mcap(tmp_path / "liar.mcap", True, declared=1024, data=bomb)
    with pytest.raises(McapReadError, match="zstd frame declares 1073741824 bytes, its record 1024"):
        list(read(path))


def test_garbage_and_cut_files_are_one_line_errors(tmp_path):
    (tmp_path / "junk.mcap").write_bytes(b"not mcap at all" * 10)
    with pytest.raises(McapReadError, match="not an MCAP file"):
        list(read(tmp_path / "junk.mcap"))
    log = McapLog(tmp_path / "ok.mcap")
    log.write_json("skynet/demo/gcs/event", "skynet.X", {}, "{}", 1.0)
    log.close()
    whole = (tmp_path / "ok.mcap").read_bytes()
    assert [m.topic for m in read(tmp_path / "ok.mcap")] == ["skynet/demo/gcs/event"]
    (tmp_path / "cut.mcap").write_bytes(whole[: len(whole) // 2])
    with pytest.raises(McapReadError):
        list(read(tmp_path / "cut.mcap"))


def test_a_chunk_within_the_bound_is_read(tmp_path):
    """The bound is on the declared size: a legitimate chunk of a few MB decompresses as before."""
    b = RecordBuilder()
    body = Message(channel_id=1, sequence=0, log_time=5, publish_time=5, data=b"x" * (4 << 20))
    body.write(b)
    raw = b.end()
    data = zstandard.ZstdCompressor().compress(raw)
    path = crafted_mcap(tmp_path / "fine.mcap", True, declared=len(raw), data=data)
    got = list(read(path))
    assert len(got) == 1 and len(got[0].data) == 4 << 20 and len(raw) < MAX_CHUNK_BYTES


def test_skynet_replay_of_the_crafted_file_is_a_one_line_error_in_little_memory(tmp_path, bomb, gateway):
    path = crafted_mcap(tmp_path / "bomb.mcap", True, data=bomb)
    # a parent of its own, so that RUSAGE_CHILDREN is this replay's peak alone
    code = textwrap.dedent(f"""
        import resource, subprocess, sys
        r = subprocess.run([sys.executable, "-m", "services.cli", "replay", {str(path)!r}, "--speed", "0",
                            *{[a for e in gateway for a in ("-e", e)]!r}], capture_output=True, text=True, timeout=120)
        sys.stdout.write(r.stderr)
        print("RC", r.returncode, "MAXRSS_KB", resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
    """)
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=180)
    out = proc.stdout
    assert "RC 2 " in out, out + proc.stderr
    errors = [ln for ln in out.splitlines() if "skynet replay: error:" in ln]
    assert len(errors) == 1 and "declares 1073741824 bytes uncompressed" in errors[0], out
    assert "Traceback" not in out, out
    peak_mb = int(out.rsplit("MAXRSS_KB", 1)[1]) / 1024
    assert peak_mb < 400, f"skynet replay peaked at {peak_mb:.0f} MB on a crafted file"
