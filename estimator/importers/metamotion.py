"""Placeholder: written next."""
NAME = "metamotion"
TITLE = "metamotion"


def sniff(source):
    return False


def read(sources, options):
    raise NotImplementedError
