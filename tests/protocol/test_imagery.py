"""The imagery frame (protocol.imagery): our own format, so the dynamic payload type, never JPEG's 26."""

from __future__ import annotations

import pytest

from protocol import codec
from protocol.imagery import pack_image, split_payload, unpack_image
from protocol.messages import ImageMeta, Intrinsics
from protocol.rtp import JPEG_PAYLOAD_TYPE, SKYNET_PAYLOAD_TYPE, RtpSender, ssrc_for


def _meta() -> ImageMeta:
    return ImageMeta(uav=2, capture_id=7, t=1.5, stamp=1000.0, cam_pos=(1.0, 2.0, 3.0),
                     cam_rot=(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
                     intrinsics=Intrinsics(width=320, height=240, fx=300.0, fy=300.0, cx=160.0, cy=120.0))


def test_frames_carry_the_dynamic_payload_type_and_round_trip() -> None:
    packet = pack_image(RtpSender(ssrc_for(2), initial_seq=9), _meta(), b"\xff\xd8jpeg", 1000.0)
    header, meta, image = unpack_image(packet)
    assert header.payload_type == SKYNET_PAYLOAD_TYPE != JPEG_PAYLOAD_TYPE
    assert packet[1] & 0x7F == 96  # on the wire, as any RTP receiver reads it
    assert (header.sequence, meta, bytes(image)) == (9, _meta(), b"\xff\xd8jpeg")


@pytest.mark.parametrize("payload", [b"", b"\x00", b"\x00\x10abc", b"\x00\x03\xff\xff\xff"])
def test_bad_payloads_are_codec_errors(payload: bytes) -> None:
    with pytest.raises(codec.CodecError):
        split_payload(payload)
