"""What the ground station needs to know to open the payload's video: ``StreamDescription``."""

from dataclasses import dataclass

#: StreamDescription.kind values, as MAVLink's VIDEO_STREAM_TYPE names them.
RTSP = "rtsp"  # VIDEO_STREAM_TYPE_RTSP (0)
RTP_UDP = "rtp_udp"  # VIDEO_STREAM_TYPE_RTPUDP (1)


@dataclass(frozen=True)
class StreamDescription:
    """The live stream as served: enough to fill VIDEO_STREAM_INFORMATION.

    ``uri``: ``rtsp://HOST:PORT/PATH`` (kind "rtsp") or ``udp://HOST:PORT`` (kind "rtp_udp": RTP
    H.264 payload type 96 sent to that address). ``width``/``height``/``fps``/``bitrate_kbps`` are
    the stream's, not the camera's; the picture is the whole camera frame scaled (not cropped or
    letterboxed), so a point normalised to the stream is the same point normalised to the camera.
    """

    uri: str
    width: int
    height: int
    fps: float
    bitrate_kbps: int
    encoding: str = "H264"
    kind: str = RTSP
    encoder: str = ""  # the GStreamer element encoding it (nvv4l2h264enc, openh264enc)
