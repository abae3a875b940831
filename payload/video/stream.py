"""The live stream: H.264 over RTSP (GStreamer's RTSP server) or, as the fallback, RTP over UDP.

RTSP: the server listens on ``video.rtsp_port`` and serves ``video.path``; its pipeline
(appsrc -> encoder -> RTP payloader) exists only while a ground station is connected, shared by
all connected clients, so nothing is encoded when nobody watches. The server's GLib main loop
runs on a thread of its own.

RTP/UDP: the pipeline runs always and sends to ``video.udp_host:udp_port`` (QGroundControl
listens on UDP 5600 for RTP H.264). Used when ``video.transport: udp`` or when the RTSP server
is not installed.
"""

import logging
import socket
import threading
from typing import Optional, Tuple

from payload.video.description import RTP_UDP, RTSP, StreamDescription
from payload.video.gst import (
    AppsrcFeed,
    OwnPipeline,
    VideoUnavailable,
    appsrc_text,
    encoder_chain,
    import_gst,
    import_rtsp_server,
    lower_streaming_threads,
)

log = logging.getLogger(__name__)

_PAYLOADER = "rtph264pay name=pay0 pt=96 config-interval=1"


def default_host() -> str:
    """This machine's address on its default route (what a ground station would reach), else
    127.0.0.1. Connecting a UDP socket sends nothing; 192.0.2.1 is TEST-NET-1."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.1", 9))
            return s.getsockname()[0]
        except OSError:
            return "127.0.0.1"


def _frame_bytes(size_wh: Tuple[int, int]) -> int:
    return size_wh[0] * size_wh[1] * 3 // 2  # I420


class RtspStream:
    """An RTSP server with one appsrc-fed, shared media at ``path``."""

    kind = RTSP

    def __init__(self, port: int, path: str, host: Optional[str], size_wh: Tuple[int, int], fps: float,
                 bitrate_kbps: int, encoder: str) -> None:
        GstRtspServer = import_rtsp_server()
        _Gst, GLib = import_gst()
        self._GstRtspServer = GstRtspServer
        self.size_wh = size_wh
        self.encoder = encoder
        self.bitrate_kbps = bitrate_kbps
        self._lock = threading.Lock()
        self._feed: Optional[AppsrcFeed] = None
        self._enc = None
        self.dropped = 0  # encoder-behind drops of media that have ended
        self.server = GstRtspServer.RTSPServer()
        self.server.set_address("0.0.0.0")
        self.server.set_service(str(port))
        factory = GstRtspServer.RTSPMediaFactory()
        factory.set_launch("( %s ! %s ! %s )" % (appsrc_text(size_wh, fps), encoder_chain(encoder, bitrate_kbps, fps),
                                                 _PAYLOADER))
        factory.set_shared(True)
        factory.connect("media-configure", self._on_media_configure)
        self.server.get_mount_points().add_factory(path, factory)
        self._context = GLib.MainContext.new()
        try:
            self._source = self.server.create_source(None)
        except GLib.Error as exc:
            raise VideoUnavailable("video.rtsp_port %d: %s" % (port, " ".join(exc.message.split()))) from None
        self._source.attach(self._context)
        self.port = self.server.get_bound_port()
        self._loop = GLib.MainLoop.new(self._context, False)
        self._thread = threading.Thread(target=self._loop.run, name="video-rtsp", daemon=True)
        self._thread.start()
        w, h = size_wh
        self.description = StreamDescription("rtsp://%s:%d%s" % (host or default_host(), self.port, path), w, h, fps,
                                             bitrate_kbps, kind=RTSP, encoder=encoder)

    def _on_media_configure(self, _factory, media) -> None:
        element = media.get_element()
        pipeline = element.get_parent()
        lower_streaming_threads((pipeline if pipeline is not None else element).get_bus())
        feed = AppsrcFeed(element.get_by_name_recurse_up("src"), _frame_bytes(self.size_wh))
        media.connect("unprepared", self._on_unprepared, feed)
        with self._lock:
            self._feed = feed
            self._enc = element.get_by_name_recurse_up("enc")
            self._enc.set_property("bitrate", self.bitrate_kbps * 1000)

    def _on_unprepared(self, _media, feed: AppsrcFeed) -> None:
        with self._lock:
            self.dropped += feed.dropped
            if self._feed is feed:
                self._feed = None
                self._enc = None

    @property
    def feed(self) -> Optional[AppsrcFeed]:
        """The appsrc to push into while a client watches, else None."""
        return self._feed

    @property
    def encoder_dropped(self) -> int:
        feed = self._feed
        return self.dropped + (feed.dropped if feed is not None else 0)

    @property
    def clients(self) -> int:
        return self.server.get_session_pool().get_n_sessions()

    def set_bitrate(self, kbps: int) -> None:
        with self._lock:
            self.bitrate_kbps = kbps
            if self._enc is not None:
                self._enc.set_property("bitrate", kbps * 1000)

    def poll(self) -> Optional[str]:
        return None  # the server reports its media's errors to the client; nothing stops the stream

    def stop(self) -> None:
        remove = self._GstRtspServer.RTSPFilterResult.REMOVE
        self.server.client_filter(lambda _server, _client: remove)  # close the clients, unpreparing the media
        self._source.destroy()
        self._loop.quit()
        self._thread.join(timeout=5.0)


class UdpStream:
    """RTP H.264 (payload type 96) to one UDP address, encoded all the time."""

    kind = RTP_UDP

    def __init__(self, host: str, port: int, size_wh: Tuple[int, int], fps: float, bitrate_kbps: int,
                 encoder: str) -> None:
        self.pipeline = OwnPipeline("%s ! %s ! %s ! udpsink host=%s port=%d sync=false async=false" % (
            appsrc_text(size_wh, fps), encoder_chain(encoder, bitrate_kbps, fps), _PAYLOADER, host, port))
        self._appsrc = self.pipeline.element("src")
        self._feed = AppsrcFeed(self._appsrc, _frame_bytes(size_wh))
        self.pipeline.play()
        w, h = size_wh
        self.description = StreamDescription("udp://%s:%d" % (host, port), w, h, fps, bitrate_kbps, kind=RTP_UDP,
                                             encoder=encoder)

    @property
    def feed(self) -> Optional[AppsrcFeed]:
        return self._feed

    @property
    def encoder_dropped(self) -> int:
        return self._feed.dropped if self._feed is not None else 0

    clients = 0

    def set_bitrate(self, kbps: int) -> None:
        self.pipeline.element("enc").set_property("bitrate", kbps * 1000)

    def poll(self) -> Optional[str]:
        """An error that stopped the stream (then the feed is gone), or None."""
        problem = self.pipeline.error()
        if problem is not None:
            self.pipeline.close()
            self._feed = None
        return problem

    def stop(self) -> None:
        self.pipeline.finish(self._appsrc, timeout_s=1.0)
        self._feed = None
