"""The REST API, version 1 (``docs/spec/api.md``)."""
