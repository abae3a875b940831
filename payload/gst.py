"""PyGObject's GStreamer, imported and initialised once for the whole process.

The camera pipeline (payload.capture.gstreamer) and the video (payload.video) both use it; each
turns ``GstUnavailable`` into its own one-line error. PyGObject is the optional ``gstreamer``
extra, so nothing imports ``gi`` before a feature that needs it is switched on.
"""

import threading

_init_lock = threading.Lock()
_initialised = False


class GstUnavailable(Exception):
    """GStreamer cannot be used from Python here; the message says why, in one line."""


def one_line(text) -> str:
    """An error text (GLib's may span lines) as one log line."""
    return " ".join(str(text).split())


def import_gst():
    """(Gst, GLib), initialised once; GstUnavailable when PyGObject or the typelibs are missing."""
    global _initialised
    try:
        import gi

        gi.require_version("Gst", "1.0")
        gi.require_version("GstApp", "1.0")
        # GstApp before any appsrc/appsink exists: PyGObject wraps an element's class once, and one
        # made without GstApp loaded never gets its methods (the capture's appsink.try_pull_sample)
        from gi.repository import GLib, Gst, GstApp  # noqa: F401
    except (ImportError, ValueError) as exc:
        raise GstUnavailable("GStreamer is not usable from Python (%s): install the gstreamer extra (PyGObject), "
                             "gir1.2-gstreamer-1.0 and gir1.2-gst-plugins-base-1.0" % one_line(exc)) from None
    with _init_lock:
        if not _initialised:
            Gst.init(None)
            _initialised = True
    return Gst, GLib
