"""Placeholder: written next."""
NAME = "apdm"
TITLE = "apdm"


def sniff(source):
    return False


def read(sources, options):
    raise NotImplementedError
