"""Live video for the ground station and onboard recording (issue 17).

- ``description``: ``StreamDescription``, what VIDEO_STREAM_INFORMATION needs to name the stream;
- ``handoff``: the newest-wins slot between the detection loop and the video thread;
- ``render``: the annotated picture (boxes, mode, score, lock state) at the stream's size;
- ``gst``: GStreamer, imported lazily (the optional ``gstreamer`` extra), and the encoder choice;
- ``stream``: H.264 over RTSP (GStreamer's RTSP server) or RTP/UDP;
- ``recorder``: rotating Matroska segments under a disk quota;
- ``output``: ``VideoOutput``, the part the service runs.

A running service names its stream with ``Service.stream_description()`` (None when no stream):
``VideoOutput.description`` of its ``Service.video``.
"""

from payload.video.description import RTP_UDP, RTSP, StreamDescription

__all__ = ["RTP_UDP", "RTSP", "StreamDescription"]
