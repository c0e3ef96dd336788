"""One module per ``armtrack`` sub-command."""
