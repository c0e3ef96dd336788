"""The REST API, version 1 (``spec/api.md``)."""
