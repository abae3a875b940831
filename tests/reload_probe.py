"""`glad-payload run` with a window on its running objects, for the reload tests.

    python tests/reload_probe.py OUT.json run --config FILE

runs the real command line (payload.cli.main) and, after each SIGHUP reload, writes OUT.json:
for every dotted config key, the values that the running components hold for it, read from
the objects that use them (the detector's stages and models, the bearing model, the publisher,
the link, the root logger). It only reads: Service.reload is wrapped, nothing is set.
"""

import json
import logging
import os
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

from payload import cli, service  # noqa: E402
from payload.config import flat_config  # noqa: E402


def running_values(svc):
    """dotted key -> [value held by each running object that uses it]."""
    seen = {}

    def add(prefix, section):
        if section is not None:
            for key, value in flat_config(section, prefix).items():
                seen.setdefault(key, []).append(value)

    g = svc.glad
    add("detector.global.motion", g.gmd.cfg)
    add("detector.local.motion", g.lmd.cfg)
    # the targets followed now, and one started now (what a target found after the reload runs with)
    for track in g.tracks + [g._new_track()]:
        add("detector.search_region", track.region.cfg)
        add("detector.switcher", track.switcher.cfg)
        seen.setdefault("detector.search_region.measurement_noise", []).append(float(track.region._kf.R[0, 0]) ** 0.5)
    add("detector.global.scan", g.cfg.global_.scan)  # read by the pipeline from its own config
    add("detector.global.appearance", g.models.global_appearance and g.models.global_appearance.cfg)
    add("detector.local.appearance", g.models.local_appearance and g.models.local_appearance.cfg)
    add("detector.classifier", g.models.classifier and g.models.classifier.cfg)
    add("detector", g.cfg)  # the switches the pipeline reads (enabled, modules, ...)
    add("camera", svc.bearings.cfg)
    add("target", svc.geo.cfg)
    if svc.camera is not None:
        add("mavlink.camera", svc.camera.cfg)
        seen.setdefault("camera.pixel_size_um", []).append(svc.camera.camera_cfg.pixel_size_um)
    if svc.publisher is not None:
        add("mavlink.outputs", svc.publisher.cfg)
    if svc.link is not None:  # the link's keys (mavlink.outputs is the publisher's)
        for key, value in flat_config(svc.link.cfg, "mavlink").items():
            if not key.startswith("mavlink.outputs."):
                seen.setdefault(key, []).append(value)
    video_cfg = svc.video.cfg if svc.video is not None else svc.cfg  # no video running: only the config holds them
    add("video", video_cfg.video)
    add("recording", video_cfg.recording)
    seen.setdefault("logging.level", []).append(logging.getLevelName(logging.getLogger().level))
    add("logging", svc.cfg.logging)  # the summary interval is read from the service's config
    return seen


def main(out_path, argv):
    reload = service.Service.reload

    def reload_and_report(self):
        ok = reload(self)
        tmp = out_path + ".tmp"
        with open(tmp, "w") as fh:
            json.dump(running_values(self), fh, default=list)
        os.replace(tmp, out_path)
        return ok

    service.Service.reload = reload_and_report
    return cli.main(argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2:]))
