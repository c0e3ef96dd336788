"""The sensor stream protocol (``spec/ingest.md``): message checks, the group-commit
writer that makes acks mean "stored", and the WebSocket endpoint."""
