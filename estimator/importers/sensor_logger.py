"""Placeholder: written next."""
NAME = "sensor-logger"
TITLE = "sensor_logger"


def sniff(source):
    return False


def read(sources, options):
    raise NotImplementedError
