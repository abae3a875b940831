"""What a reload changes: the dotted keys that differ between two configs, and which of them
only a restart applies.

Each running component applies its own section on SIGHUP and returns the keys it applied
(``section_changes`` gives it them); a key that nobody applies live is restart-only: it is
listed in ``RESTART_KEYS`` (and marked ``[restart]`` in configs/default.yaml) and refused at
reload, keeping its running value.
"""

from typing import Any, Dict, List

from pydantic import BaseModel

from payload.config.schema import Config

#: Dotted prefixes whose change needs a restart; everything else is applied on SIGHUP.
RESTART_KEYS = (
    "capture",
    "mavlink.enabled",
    "mavlink.connection",
    "mavlink.baud",
    "mavlink.system_id",
    "mavlink.component_id",
    "mavlink.component_type",
    "mavlink.signing",
    "detector.backend",
    "detector.threads",
    "detector.fp16",
    "detector.engine_cache_dir",
    "detector.global.appearance.model",
    "detector.global.appearance.input_wh",
    "detector.local.appearance.model",
    "detector.local.appearance.input_wh",
    "detector.classifier.model",
    "detector.verifier.model",
    "outputs",
    # video and recording: all but payload.video.output.LIVE_KEYS
    "video.enabled",
    "video.transport",
    "video.rtsp_port",
    "video.path",
    "video.advertise_host",
    "video.udp_host",
    "video.udp_port",
    "video.width",
    "video.height",
    "video.fps",
    "video.encoder",
    "recording.enabled",
    "recording.dir",
    "recording.segment_s",
)


def _flatten(data: Any, prefix: str = "") -> Dict[str, Any]:
    if isinstance(data, dict):
        out = {}
        for key, value in data.items():
            out.update(_flatten(value, "%s.%s" % (prefix, key) if prefix else str(key)))
        return out
    return {prefix: data}


def flat_config(cfg: BaseModel, prefix: str = "") -> Dict[str, Any]:
    """Every leaf of a config (or of one section, under ``prefix``) by its dotted YAML key,
    e.g. 'detector.global.appearance.confidence'."""
    return _flatten(cfg.model_dump(by_alias=True), prefix)


def section_changes(old: BaseModel, new: BaseModel, prefix: str) -> List[str]:
    """Dotted keys (under ``prefix``, e.g. 'mavlink.outputs') that differ between two sections."""
    a, b = flat_config(old, prefix), flat_config(new, prefix)
    return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


def changed_keys(old: Config, new: Config) -> List[str]:
    """Dotted keys whose values differ between two configs."""
    return section_changes(old, new, "")


def is_restart_key(key: str) -> bool:
    return any(key == p or key.startswith(p + ".") for p in RESTART_KEYS)


def restart_required(old: Config, new: Config) -> List[str]:
    """Dotted keys that differ between two configs and only take effect after a restart."""
    return [k for k in changed_keys(old, new) if is_restart_key(k)]
