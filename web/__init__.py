"""armtrack."""
