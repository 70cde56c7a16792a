"""SDP files for the video streams (RFC 8866), one per stream, for players to open.

Design notes: docs/operator-view.md (services/video/sdp.py).
"""

from __future__ import annotations

import ipaddress
from typing import Literal

from protocol.rtp import JPEG_PAYLOAD_TYPE

from .packetize import H264_PAYLOAD_TYPE

Codec = Literal["h264", "mjpeg"]


def sdp(codec: Codec, host: str, port: int, name: str, session_id: int = 0, framerate: float | None = None) -> str:
    """The SDP text of one stream sent to ``host:port`` (IPv4)."""
    ip = ipaddress.IPv4Address(host)
    if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
        raise ValueError(f"port must be an int in 1..65535, got {port!r}")
    if codec == "h264":
        media = [f"m=video {port} RTP/AVP {H264_PAYLOAD_TYPE}", f"a=rtpmap:{H264_PAYLOAD_TYPE} H264/90000",
                 f"a=fmtp:{H264_PAYLOAD_TYPE} packetization-mode=1"]
    elif codec == "mjpeg":
        media = [f"m=video {port} RTP/AVP {JPEG_PAYLOAD_TYPE}", f"a=rtpmap:{JPEG_PAYLOAD_TYPE} JPEG/90000"]
    else:
        raise ValueError(f"codec must be h264 or mjpeg, got {codec!r}")
    if framerate:
        media.append(f"a=framerate:{framerate:g}")
    lines = ["v=0", f"o=- {int(session_id)} 1 IN IP4 {ip}", f"s={name}", f"c=IN IP4 {ip}", "t=0 0", *media]
    return "\r\n".join(lines) + "\r\n"
