"""``glad-payload soak``: the real service for N minutes against the fake autopilot, with faults.

``glad-payload run`` runs as a subprocess on a generated config: a looping image folder paced
at camera rate (a synthetic clip with a drone in every frame, played forwards then backwards so
the loop has no jump), MAVLink over UDP loopback to ``sitl/fake_autopilot.py``, outputs in the
soak's folder. On a schedule, one fault at a time, in turn:

- ``autopilot_restart``: the autopilot is killed (SIGKILL) and started again after a pause;
- ``garbage``: a burst of random UDP datagrams at the payload's MAVLink socket;
- ``corrupt_frames``: three frames of the folder become a zero-byte, a truncated and a random
  file for two passes through the clip, then are restored (``--no-corrupt-frames`` leaves them
  out); survived once the service's summary counts one as unreadable and frames go on;
- ``reload_good`` / ``reload_bad``: SIGHUP with a changed valid config, and with a broken one
  (syntax error, bad value, unknown key, not UTF-8, in turn), the good file put back after.

Meanwhile the service's RSS, open fds and threads are sampled from /proc, and its decisions CSV,
log and the autopilot's record are read as they grow. The report: frames processed, faults
survived per kind, messages lost, resource use at the start (after the warm-up) and the end
(RSS the median of three samples; open fds and threads the fewest in five, since a frame file
open for reading lands in a sample now and then while a leak stays),
and per autopilot restart the delay until target messages resumed. Exit status 1 when the
service died or a criterion failed.
"""

#: The fault kinds, injected in this order, one every ``--every`` seconds.
KINDS = ("autopilot_restart", "garbage", "corrupt_frames", "reload_good", "reload_bad")


def add_arguments(p) -> None:
    """The ``soak`` subcommand's options (here, so that cli.py stays a list of commands)."""
    p.add_argument("--minutes", type=float, required=True, help="how long to run (after the service's first frame)")
    p.add_argument("--out", default="soak-output",
                   help="folder for the clip, config, service log, decisions and the autopilot's record")
    p.add_argument("--config", "-c", default=None,
                   help="base YAML (capture, mavlink.connection and outputs are the soak's)")
    p.add_argument("--every", type=float, default=None,
                   help="seconds between faults (default 20; soaks under 5 minutes: minutes*60/8, at least 4)")
    p.add_argument("--no-corrupt-frames", action="store_true", help="leave out the corrupt_frames fault")
    p.add_argument("--fps", type=float, default=30.0, help="camera rate the folder is paced at")
    p.add_argument("--size", nargs=2, type=int, default=(960, 540), metavar=("W", "H"), help="clip frame size")
    p.add_argument("--clip-frames", type=int, default=None,
                   help="frames rendered, played forwards then backwards (default 90, fewer when faults come "
                        "so often that corrupt frames kept two passes would overlap the next)")
    p.add_argument("--seed", type=int, default=2, help="synthetic scene (seed 2: the drone is in view throughout)")
