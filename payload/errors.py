"""The few named errors of the payload. Each carries a one-line, operator-readable message."""


class PayloadError(Exception):
    """Base class: str(error) is the single line shown to the operator."""


class ConfigError(PayloadError):
    """The YAML configuration is invalid. `problems` holds one line per problem."""

    def __init__(self, problems):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


class SourceError(PayloadError):
    """A frame source cannot be opened (missing file or device, broken pipeline)."""


class CameraLost(PayloadError):
    """A live frame source stopped delivering frames."""


class BackendUnavailable(PayloadError):
    """An inference backend or model file cannot be used."""


class ModelError(PayloadError):
    """An ONNX model file is missing or does not have the expected inputs/outputs."""


class DataError(PayloadError):
    """A detections CSV or label file is missing or malformed (the message names file:line)."""
