"""Live video and onboard recording (payload.video) with real GStreamer pipelines: the payload's
RTSP server read by a real rtspsrc client, the RTP/UDP fallback read by a real udpsrc receiver,
recordings decoded by OpenCV's FFmpeg, a disk limit the kernel enforces (RLIMIT_FSIZE)."""

import glob
import logging
import os
import re
import resource
import socket
import subprocess
import sys
import threading
import time

import cv2
import numpy as np
import pytest
import yaml

from payload.config import parse_config
from payload.detect.pipeline import GladResult
from payload.errors import ConfigError
from payload.types import Detections, Frame, Target

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_RTP_CAPS = "application/x-rtp,media=video,encoding-name=H264,payload=96,clock-rate=90000"


# --- config: no GStreamer needed ------------------------------------------------------------


@pytest.mark.parametrize("section, message", [
    ({"outputs": {"video": True}}, "outputs.video: unknown key"),
    ({"video": {"path": "glad"}}, "video.path: 'glad': expected an RTSP mount path such as /glad"),
    ({"video": {"width": 641}}, "width 641, height 720: both must be even"),
    ({"video": {"encoder": "x264enc"}}, "video.encoder: 'x264enc' is not one of"),
    ({"recording": {"enabled": True}}, "recording.enabled needs recording.dir"),
    ({"recording": {"enabled": True, "dir": "/tmp/r", "quota_mb": 0.5}, "video": {"bitrate_kbps": 4000}},
     "recording.quota_mb 0.5 holds less than 3 s of video at video.bitrate_kbps 4000: raise it to 1.5 or more"),
])
def test_video_config_errors_are_one_operator_line(section, message):
    with pytest.raises(ConfigError) as err:
        parse_config(section)
    assert len(err.value.problems) == 1 and message in err.value.problems[0], err.value.problems


def test_restart_and_live_keys_cover_the_video_sections():
    from payload.config import flat_config, is_restart_key

    live = {"video.annotate", "video.bitrate_kbps", "recording.annotated", "recording.quota_mb"}
    keys = [k for k in flat_config(parse_config({})) if k.startswith(("video.", "recording."))]
    assert {k for k in keys if not is_restart_key(k)} == live
    try:
        from payload.video.output import LIVE_KEYS
    except ImportError:  # no PyGObject needed for the module itself, but be explicit if that changes
        pytest.fail("payload.video.output must import without GStreamer")
    assert set(LIVE_KEYS) == live


# --- GStreamer fixtures -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def gst():
    from payload.video.gst import VideoUnavailable, has_elements, import_gst, import_rtsp_server

    try:
        Gst, _ = import_gst()
        import_rtsp_server()
    except VideoUnavailable as exc:
        pytest.skip(str(exc))
    missing = [e for e in ("openh264enc", "h264parse", "avdec_h264", "rtspsrc", "splitmuxsink", "matroskamux")
               if not has_elements(e)]
    if missing:
        pytest.skip("GStreamer elements missing: %s (scripts/install-system-deps.sh)" % ", ".join(missing))
    return Gst


def video_cfg(**video):
    base = {"enabled": True, "rtsp_port": 0, "advertise_host": "127.0.0.1", "width": 320, "height": 240,
            "fps": 30.0, "annotate": False}
    base.update(video)
    return parse_config({"video": base})


def frame(index, image):
    return Frame(image, index, time.monotonic_ns(), time.time_ns())


def halves(w, h):
    """Left half white, right half black: survives H.264 and says which way round the picture is."""
    img = np.zeros((h, w, 3), np.uint8)
    img[:, : w // 2] = 255
    return img


class Receiver:
    """A real client pipeline ending in appsink: decoded BGR frames, collected on a thread."""

    def __init__(self, Gst, head):
        self.Gst = Gst
        self.pipeline = Gst.parse_launch(
            "%s ! rtph264depay ! avdec_h264 ! videoconvert ! video/x-raw,format=BGR ! "
            "appsink name=sink sync=false max-buffers=50" % head)
        self.sink = self.pipeline.get_by_name("sink")
        self.frames = []
        self._stop = threading.Event()
        self.pipeline.set_state(Gst.State.PLAYING)
        self._thread = threading.Thread(target=self._pull, daemon=True)
        self._thread.start()

    def _pull(self):
        while not self._stop.is_set():
            sample = self.sink.emit("try-pull-sample", int(0.1e9))
            if sample is None:
                continue
            caps = sample.get_caps().get_structure(0)
            w, h = caps.get_value("width"), caps.get_value("height")
            buf = sample.get_buffer()
            ok, info = buf.map(self.Gst.MapFlags.READ)
            if ok:
                self.frames.append(np.frombuffer(info.data, np.uint8)[: w * h * 3].reshape(h, w, 3).copy())
                buf.unmap(info)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=5)
        self.pipeline.set_state(self.Gst.State.NULL)


def feed_until(out, receiver, n_frames, image_at, timeout_s=20.0, period_s=1 / 30.0):
    deadline = time.monotonic() + timeout_s
    i = 0
    while len(receiver.frames) < n_frames and time.monotonic() < deadline:
        out.submit(frame(i, image_at(i)), None, "searching")
        i += 1
        time.sleep(period_s)
    return i


def check_halves(img):
    h, w = img.shape[:2]
    left, right = img[:, : w // 2 - 8].mean(), img[:, w // 2 + 8:].mean()
    assert left > 230 and right < 25, (left, right)


# --- the stream -------------------------------------------------------------------------------


def test_rtsp_stream_is_decoded_by_a_real_rtspsrc_client(gst):
    from payload.video.output import VideoOutput

    out = VideoOutput.open(video_cfg())
    receiver = None
    try:
        d = out.description
        assert d.kind == "rtsp" and d.encoding == "H264" and d.encoder == "openh264enc"
        assert d.uri.startswith("rtsp://127.0.0.1:") and d.uri.endswith("/glad") and (d.width, d.height) == (320, 240)
        # nobody watching: nothing is encoded
        for i in range(5):
            out.submit(frame(i, halves(640, 480)), None, "searching")
            time.sleep(0.05)
        assert out.stats().streamed == 0
        receiver = Receiver(gst, "rtspsrc location=%s latency=0" % d.uri)
        feed_until(out, receiver, 10, lambda i: halves(640, 480))  # scaled 640x480 -> 320x240 on the way
        assert len(receiver.frames) >= 10
        assert out.stats().clients == 1
        for img in receiver.frames[-3:]:
            assert img.shape == (240, 320, 3)
            check_halves(img)
    finally:
        if receiver is not None:
            receiver.close()
        out.stop()


def test_a_ground_station_can_leave_and_come_back(gst):
    """The media ends with its last client (nothing encoded meanwhile) and starts again for the next."""
    from payload.video.output import VideoOutput

    out = VideoOutput.open(video_cfg())
    try:
        for visit in range(2):
            receiver = Receiver(gst, "rtspsrc location=%s latency=0" % out.description.uri)
            feed_until(out, receiver, 5, lambda i: halves(320, 240))
            assert len(receiver.frames) >= 5, visit
            check_halves(receiver.frames[-1])
            receiver.close()  # TEARDOWN
            deadline = time.monotonic() + 10
            # the media's end and the client's "closed" signal come separately: wait for both
            while (out.stream.feed is not None or out.stats().clients) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert out.stream.feed is None and out.stats().clients == 0
    finally:
        out.stop()


def test_the_stream_shows_the_target_box_where_glad_put_it(gst):
    """Annotated: the target's box, drawn at the scaled position, reaches the client."""
    from payload.video.output import VideoOutput

    out = VideoOutput.open(video_cfg(annotate=True))
    receiver = Receiver(gst, "rtspsrc location=%s latency=0" % out.description.uri)
    box = np.array([200, 160, 300, 260], np.float32)  # in the 640x480 camera frame
    dets = Detections(box[None], np.array([0.9], np.float32), np.array(["GAD"]))
    try:
        deadline = time.monotonic() + 20
        i = 0
        while len(receiver.frames) < 10 and time.monotonic() < deadline:
            target = Target(i, 0, box.copy(), 0.9, "GAD", measured=True)
            result = GladResult(i, 0, "global", dets, dets, target, None)
            out.submit(frame(i, np.zeros((480, 640, 3), np.uint8)), result, "detected")
            i += 1
            time.sleep(1 / 30.0)
        img = receiver.frames[-1]
        # GAD's green box around x 100..150, y 80..130 at 320x240 (drawn 4 px outside, 2 px wide)
        green = img[85:125, 80:120, 1].mean(axis=0)
        assert abs(80 + int(np.argmax(green)) - 96) <= 1 and green.max() > 150, green.round()
        assert img[95:115, 110:140].mean() < 30  # nothing drawn inside the box
    finally:
        receiver.close()
        out.stop()


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_rtp_udp_fallback_when_rtsp_cannot_serve_is_decoded_by_udpsrc(gst, caplog):
    """The RTSP port is taken: one line, and the stream goes out as RTP/UDP instead."""
    from payload.video.output import VideoOutput

    blocker = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    blocker.bind(("0.0.0.0", 0))
    blocker.listen(1)
    port = free_udp_port()
    receiver = Receiver(gst, 'udpsrc port=%d caps="%s"' % (port, _RTP_CAPS))
    caplog.set_level(logging.INFO)
    out = VideoOutput.open(video_cfg(rtsp_port=blocker.getsockname()[1], udp_port=port))
    try:
        assert out.description.kind == "rtp_udp" and out.description.uri == "udp://127.0.0.1:%d" % port
        lines = [r.getMessage() for r in caplog.records if "no RTSP" in r.getMessage()]
        assert len(lines) == 1 and "streaming RTP/UDP to 127.0.0.1:%d instead" % port in lines[0], lines
        feed_until(out, receiver, 10, lambda i: halves(320, 240))
        assert len(receiver.frames) >= 10
        check_halves(receiver.frames[-1])
    finally:
        receiver.close()
        out.stop()
        blocker.close()


def test_encoder_behind_drops_are_counted_and_submit_never_waits(gst):
    """Fed 1080p noise far faster than the software encoder takes it: the loop's hand-over stays
    quick, and every frame is accounted for as streamed or dropped (in the slot or at the encoder)."""
    from payload.video.output import VideoOutput

    port = free_udp_port()
    out = VideoOutput.open(video_cfg(transport="udp", udp_port=port, width=1920, height=1080, fps=60.0,
                                     bitrate_kbps=20000))
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, (1080, 1920, 3), np.uint8) for _ in range(4)]
    waits = []
    try:
        for i in range(300):
            t = time.perf_counter()
            out.submit(frame(i, images[i % 4]), None, "searching")
            waits.append(time.perf_counter() - t)
            time.sleep(0.002)
        time.sleep(1.0)
        st = out.stats()
    finally:
        out.stop()
    assert max(waits) < 0.05, max(waits)  # a lock and a reference, never the encoder
    assert st.submitted == 300
    assert st.dropped > 0 and st.stream_dropped > 0, st
    assert st.streamed + st.stream_dropped + st.dropped == st.submitted, st


def test_bitrate_reloads_live_restart_keys_do_not(gst):
    from payload.config import config_with
    from payload.video.output import VideoOutput

    cfg = video_cfg(transport="udp", udp_port=free_udp_port())
    out = VideoOutput.open(cfg)
    try:
        new = config_with(cfg, **{"video.bitrate_kbps": 800, "video.annotate": True, "video.width": 640})
        assert sorted(out.apply(new)) == ["video.annotate", "video.bitrate_kbps"]
        assert out.stream.pipeline.element("enc").get_property("bitrate") == 800000
        assert out.cfg.video.annotate and out.cfg.video.width == 320
    finally:
        out.stop()


# --- recording --------------------------------------------------------------------------------


_NOISE = np.random.default_rng(3).integers(0, 256, (8, 96, 96, 3), np.uint8)


def moving_scene(i, w=640, h=360):
    """A grey sky, a moving white box and a patch of changing texture (so the encoder spends bits)."""
    img = np.full((h, w, 3), 90, np.uint8)
    img[200:296, 300:396] = _NOISE[i % len(_NOISE)]
    cv2.rectangle(img, (20 + (i * 7) % (w - 80), 100), (60 + (i * 7) % (w - 80), 140), (255, 255, 255), -1)
    return img


def record(out, seconds, fps=15.0):
    t0 = time.monotonic()
    i = 0
    while time.monotonic() - t0 < seconds:
        out.submit(frame(i, moving_scene(i)), None, "searching")
        i += 1
        time.sleep(1.0 / fps)
    return i


def decoded_frames(path):
    cap = cv2.VideoCapture(path)
    n = 0
    size = None
    while True:
        ok, img = cap.read()
        if not ok:
            break
        n += 1
        size = img.shape
    cap.release()
    return n, size


def rec_cfg(directory, **recording):
    rec = {"enabled": True, "dir": str(directory)}
    rec.update(recording)
    return parse_config({"video": {"width": 320, "height": 180, "fps": 15.0, "bitrate_kbps": 200},
                         "recording": rec})


def test_recording_rotates_by_time_and_keeps_the_quota(gst, tmp_path):
    from payload.video.output import VideoOutput

    old = tmp_path / "glad-20200101-000000-00000.mkv"  # an earlier run's segment: oldest, goes first
    old.write_bytes(b"\0" * 50000)
    out = VideoOutput.open(rec_cfg(tmp_path, segment_s=1.0, quota_mb=0.1))
    assert out.stream is None and out.description is None
    record(out, 7.0)
    deleted = out.recorder.deleted
    out.stop()
    segments = sorted(glob.glob(str(tmp_path / "glad-*.mkv")))
    assert not old.exists() and deleted >= 2, (deleted, segments)
    assert sum(os.path.getsize(p) for p in segments) <= 0.1e6
    assert len(segments) >= 2
    for path in segments:
        n, size = decoded_frames(path)
        assert n >= 5 and size == (180, 320, 3), (path, n, size)
    # this run's numbering is consecutive up to the newest: only the oldest ones went
    numbers = [int(p[-9:-4]) for p in segments]
    assert numbers == list(range(numbers[0], numbers[0] + len(numbers))) and numbers[0] > 0


def test_quota_smaller_than_a_segment_cuts_segments_by_size(gst, tmp_path):
    """segment_s 60 but a quota that a minute would overflow: segments are cut at a third of it."""
    from payload.video.output import VideoOutput

    out = VideoOutput.open(rec_cfg(tmp_path, segment_s=60.0, quota_mb=0.09))
    record(out, 8.0)
    out.stop()
    segments = sorted(glob.glob(str(tmp_path / "glad-*.mkv")))
    assert int(segments[-1][-9:-4]) >= 2, segments  # at least 3 segments in 8 s, not one of 60 s
    assert sum(os.path.getsize(p) for p in segments) <= 0.09e6


def test_unwritable_recording_dir_is_one_line_and_the_stream_goes_on(gst, tmp_path, caplog):
    from payload.video.output import VideoOutput

    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    cfg = parse_config({"video": {"enabled": True, "transport": "udp", "udp_port": free_udp_port(),
                                  "width": 320, "height": 240},
                        "recording": {"enabled": True, "dir": str(blocker / "rec")}})
    caplog.set_level(logging.INFO)
    out = VideoOutput.open(cfg)
    try:
        lines = [r.getMessage() for r in caplog.records if "recording" in r.getMessage()]
        assert lines == ["recording off: recording.dir %s: Not a directory; detection goes on" % (blocker / "rec")]
        assert out.recorder is None and out.stream is not None
    finally:
        out.stop()


# --- through the service ----------------------------------------------------------------------


def service_cfg(tmp_path, **sections):
    cfg = {"capture": {"source": "synthetic", "synthetic": {"seed": 7, "width": 640, "height": 360, "frames": 0}},
           "mavlink": {"enabled": False}, "logging": {"summary_interval_s": 1.0}}
    cfg.update(sections)
    return cfg


def test_the_service_serves_its_stream_and_names_it(gst, tmp_path):
    """A real service in this process: its RTSP server, opened by the URI it describes, gives
    decodable annotated frames of the synthetic scene while detection runs."""
    from payload.service import Service

    cfg = parse_config(service_cfg(tmp_path, video={"enabled": True, "rtsp_port": 0, "advertise_host": "127.0.0.1",
                                                    "width": 320, "height": 180}))
    service = Service(cfg)
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    receiver = None
    try:
        deadline = time.monotonic() + 60
        while service.stream_description() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        d = service.stream_description()
        assert d is not None and d.uri.startswith("rtsp://127.0.0.1:") and (d.width, d.height, d.fps) == (320, 180, 15.0)
        receiver = Receiver(gst, "rtspsrc location=%s latency=0" % d.uri)
        while len(receiver.frames) < 5 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(receiver.frames) >= 5 and receiver.frames[-1].shape == (180, 320, 3)
        assert service.video.stats().streamed >= 5
    finally:
        if receiver is not None:
            receiver.close()
        service.stop()
        runner.join(timeout=30)
    assert not runner.is_alive()
    assert service.stats.frames > 0


def _limit_file_size(limit):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


@pytest.mark.slow
def test_disk_full_stops_recording_with_one_line_and_detection_goes_on(gst, tmp_path):
    """The kernel refuses to grow any file past 60 kB (RLIMIT_FSIZE, as a full disk refuses a
    write; the CSVs of 120 frames stay under it): the payload process logs one line, stops
    recording, and every frame the paced scene delivered goes all the way through (a frame the
    loaded machine missed is dropped or late, counted, as from a camera)."""
    out_dir = tmp_path / "out"
    cfg = service_cfg(tmp_path, outputs={"directory": str(out_dir)},
                      video={"width": 640, "height": 360, "bitrate_kbps": 4000},
                      recording={"enabled": True, "dir": str(tmp_path / "rec"), "quota_mb": 100})
    cfg["capture"]["synthetic"]["frames"] = 120
    cfg["capture"]["pace"] = True  # camera rate: the recording gets seconds of video to write
    path = tmp_path / "payload.yaml"
    path.write_text(yaml.safe_dump(cfg))
    log_path = tmp_path / "payload.log"
    with open(str(log_path), "w") as log_file:
        proc = subprocess.run([sys.executable, "-m", "payload", "run", "--config", str(path)], cwd=REPO,
                              stdout=subprocess.DEVNULL, stderr=log_file, timeout=300,
                              preexec_fn=_limit_file_size(60000), env=dict(os.environ, PYTHONUNBUFFERED="1"))
    log = log_path.read_text()
    assert proc.returncode == 0, log[-3000:]
    stopped = [line for line in log.splitlines() if "recording stopped" in line]
    assert len(stopped) == 1 and "File too large" in stopped[0], log[-3000:]
    final = [line for line in log.splitlines() if "final fps=" in line]
    assert len(final) == 1, log[-3000:]
    counts = dict(re.findall(r" (frames|drops|late)=(\d+)", final[0]))
    processed, missed = int(counts["frames"]), int(counts["drops"]) + int(counts.get("late", 0))
    assert processed + missed == 120 and processed >= 60, final[0]
    with open(str(out_dir / "decisions.csv")) as fh:
        assert sum(1 for _ in fh) - 1 == processed  # every frame delivered went all the way through
    segments = glob.glob(str(tmp_path / "rec" / "glad-*.mkv"))
    assert len(segments) == 1 and os.path.getsize(segments[0]) == 60000  # cut off by the limit


def _run_without(blocked, argv, timeout_s=300):
    """``glad-payload ARGV`` in a fresh interpreter where the modules ``blocked`` cannot be imported,
    as on a machine without them (an import of a module set to None in sys.modules raises ImportError)."""
    code = ("import sys\nfor name in %r:\n    sys.modules[name] = None\n"
            "from payload.cli import main\nsys.exit(main(%r))" % (list(blocked), list(argv)))
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=timeout_s,
                          env=dict(os.environ, PYTHONUNBUFFERED="1"))


@pytest.mark.slow
def test_without_pygobject_video_is_one_line_and_detection_goes_on(tmp_path):
    """Runs wherever the tests run (the 3.8 venv has no PyGObject; elsewhere it is blocked here)."""
    cfg = service_cfg(tmp_path, outputs={"directory": str(tmp_path / "out")}, video={"enabled": True},
                      recording={"enabled": True, "dir": str(tmp_path / "rec")})
    cfg["capture"]["synthetic"]["frames"] = 20
    path = tmp_path / "payload.yaml"
    path.write_text(yaml.safe_dump(cfg))
    proc = _run_without(["gi"], ["run", "--config", str(path)])
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = [line for line in proc.stderr.splitlines() if " WARNING " in line or " ERROR " in line]
    assert len(lines) == 1, lines
    assert lines[0].endswith("video and recording off: GStreamer is not usable from Python (import of gi halted; "
                             "None in sys.modules): install the gstreamer extra (PyGObject), gir1.2-gstreamer-1.0 and "
                             "gir1.2-gst-plugins-base-1.0; detection goes on"), lines[0]
    assert " frames=20 " in proc.stderr.splitlines()[-1]
    assert not os.path.exists(str(tmp_path / "rec"))


@pytest.mark.slow
def test_demo_without_the_rtsp_server_streams_rtp_udp_and_says_where(gst, tmp_path):
    proc = _run_without(["gi.repository.GstRtspServer"], ["demo", "--out", str(tmp_path), "--frames", "15"])
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "live video         udp://127.0.0.1:5600  (1280x720 H.264 openh264enc)" in proc.stdout, proc.stdout
    assert "no RTSP (the RTSP server is not usable from Python" in proc.stderr
    assert "frames processed   15" in proc.stdout


def test_sighup_reload_sets_the_bitrate_live_and_refuses_the_size(gst, tmp_path, caplog):
    """Through the service's reload: video.bitrate_kbps reaches the running encoder, video.width
    (restart-only) is named in one line and keeps its running value."""
    from payload.config import load_run_config
    from payload.service import Service

    data = service_cfg(tmp_path, video={"enabled": True, "transport": "udp", "udp_port": free_udp_port(),
                                        "width": 320, "height": 180})
    path = tmp_path / "payload.yaml"
    path.write_text(yaml.safe_dump(data))
    service = Service(load_run_config(str(path)), config_path=str(path))
    caplog.set_level(logging.INFO)
    runner = threading.Thread(target=service.run, daemon=True)
    runner.start()
    try:
        deadline = time.monotonic() + 60
        while service.stats.frames < 3 and time.monotonic() < deadline:
            time.sleep(0.1)
        data["video"].update(bitrate_kbps=700, width=640)
        path.write_text(yaml.safe_dump(data))
        service._reload.set()  # what SIGHUP does
        while not any("reload: applied" in r.getMessage() for r in caplog.records) and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        service.stop()
        runner.join(timeout=30)
    messages = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("reload: applied") and m.endswith("changed=video.bitrate_kbps") for m in messages), messages
    assert "reload: these changes need a restart and are not applied yet: video.width" in messages
    assert service.video.stream.pipeline.element("enc").get_property("bitrate") == 700000
    assert service.cfg.video.bitrate_kbps == 700 and service.cfg.video.width == 320
