"""The estimator's exception tree: every error the numerics raise derives from EstimatorError."""


class EstimatorError(Exception):
    """Base of every error raised by ``armtrack.estimator``."""


class InvalidRecording(EstimatorError):
    """A recording file breaks ``docs/spec/recording.md``; the message names the line and the
    rule."""

    def __init__(self, message: str, line: int | None = None):
        super().__init__(f"line {line}: {message}" if line is not None else message)
        self.line = line
        self.rule = message


class InvalidShape(EstimatorError, ValueError):
    """An array has the wrong shape; the message says what was expected and what came."""


class InvalidArgument(EstimatorError, ValueError):
    """A parameter is out of its allowed range or names something unknown."""
