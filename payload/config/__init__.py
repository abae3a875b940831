"""The payload's configuration: a typed object built once from YAML.

- ``schema``: every section and key with its default, bounds and rules (values only);
- ``loading``: bounded reading of the YAML file and one operator-readable line per problem;
- ``checks``: the files and folders a config names, as ``run`` needs them (``load_run_config``);
- ``reload``: what a reload changes and which keys only a restart applies.
"""

from payload.config.checks import (
    file_problems,
    load_run_config,
    load_signing_key,
    path_problem,
    writable_dir_problem,
)
from payload.config.loading import MAX_BYTES, MAX_NODES, config_with, load_config, parse_config, read_yaml
from payload.config.reload import (
    RESTART_KEYS,
    changed_keys,
    flat_config,
    is_restart_key,
    restart_required,
    section_changes,
)
from payload.config.schema import (
    AppearanceConfig,
    CameraConfig,
    CaptureConfig,
    ClassifierConfig,
    Config,
    DetectorConfig,
    GlobalStageConfig,
    LoggingConfig,
    MavlinkCameraConfig,
    MavlinkConfig,
    MavlinkOutputsConfig,
    MotionConfig,
    MountConfig,
    OutputsConfig,
    RecordingConfig,
    Retry,
    ScanConfig,
    SearchRegionConfig,
    Section,
    SigningConfig,
    StageConfig,
    SwitcherConfig,
    SyntheticSceneConfig,
    TargetConfig,
    TargetsConfig,
    VerifierConfig,
    VideoConfig,
    check_connection,
    connection_problem,
)

__all__ = [
    "MAX_BYTES", "MAX_NODES", "RESTART_KEYS", "AppearanceConfig", "CameraConfig", "CaptureConfig", "ClassifierConfig",
    "Config", "DetectorConfig", "GlobalStageConfig", "LoggingConfig", "MavlinkCameraConfig", "MavlinkConfig", "MavlinkOutputsConfig",
    "MotionConfig", "MountConfig", "OutputsConfig", "RecordingConfig", "Retry", "ScanConfig", "SearchRegionConfig", "Section",
    "SigningConfig", "StageConfig", "SwitcherConfig", "SyntheticSceneConfig", "TargetConfig", "TargetsConfig", "VerifierConfig", "VideoConfig",
    "changed_keys", "check_connection",
    "config_with", "connection_problem", "file_problems", "flat_config", "is_restart_key", "load_config",
    "load_run_config", "load_signing_key", "parse_config", "path_problem", "read_yaml", "restart_required",
    "section_changes", "writable_dir_problem",
]
