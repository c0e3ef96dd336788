"""Placeholder: written next."""
NAME = "generic"
TITLE = "generic"


def sniff(source):
    return False


def read(sources, options):
    raise NotImplementedError
