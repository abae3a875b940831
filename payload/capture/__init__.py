"""Frame sources: cameras (V4L2, GStreamer) and recordings (video file, image folder, synthetic).

``open_source(cfg.capture)`` builds the source named in the config; the caller opens it
(``with open_source(cfg) as source:``). With ``capture.pace`` a recording plays at camera rate
through the one paced path, payload.capture.paced. Heavy or optional imports (PyGObject, the synthetic
scene renderer) happen only for the kind that needs them.
"""

from payload.capture.base import EndOfStream, FrameSource, SourceStats
from payload.config import CaptureConfig
from payload.errors import ConfigError

__all__ = ["EndOfStream", "FrameSource", "SourceStats", "open_source"]


def open_source(cfg: CaptureConfig) -> FrameSource:
    """The frame source named by ``cfg.source``, not yet opened.

    ``cfg.pace`` plays a recording (file, folder, synthetic scene) as a camera at its rate
    (``cfg.fps``; the scene's own ``synthetic.fps``): payload.capture.paced wraps the unpaced reader.
    Unpaced, a file or folder is decoded a few frames ahead on its own thread (payload.capture.readahead).
    """
    if cfg.source in ("v4l2", "gstreamer"):
        return _camera(cfg)
    recording = _recording(cfg)
    if not cfg.pace:
        if cfg.source in ("file", "folder"):
            from payload.capture.readahead import ReadAhead

            return ReadAhead(recording)
        return recording
    from payload.capture.paced import PacedSource

    return PacedSource(recording, cfg.synthetic.fps if cfg.source == "synthetic" else cfg.fps)


def _recording(cfg: CaptureConfig) -> FrameSource:
    """The unpaced reader of a recording: frames as fast as they are asked for."""
    if cfg.source == "synthetic":
        from payload.capture.synthetic import SyntheticSource

        return SyntheticSource(cfg.synthetic)
    if cfg.source == "file":
        from payload.capture.file import VideoFileSource

        return VideoFileSource(cfg.path, fps=cfg.fps, loop=cfg.loop)
    if cfg.source == "folder":
        from payload.capture.file import ImageFolderSource

        return ImageFolderSource(cfg.path, fps=cfg.fps, loop=cfg.loop)
    raise ConfigError(["capture.source: %r is not one of synthetic, file, folder, v4l2, gstreamer" % (cfg.source,)])


def _camera(cfg: CaptureConfig) -> FrameSource:
    if cfg.source == "v4l2":
        from payload.capture.v4l2 import V4L2Source

        return V4L2Source(cfg.device, width=cfg.width, height=cfg.height, fps=cfg.fps, fourcc=cfg.fourcc, retry=cfg.retry)
    from payload.capture.gstreamer import GStreamerSource

    return GStreamerSource(cfg.pipeline, retry=cfg.retry)
