"""Live estimation: a worker per streaming session runs the streaming pipeline off the
event loop and publishes poses and the running range of motion to the patient's viewers."""
