"""The sensor stream protocol (``docs/spec/ingest.md``): message checks, the group-commit
writer that makes acks mean "stored", and the WebSocket endpoint."""
