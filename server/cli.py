"""The ``armtrack`` command line."""
def main(argv=None) -> int:
    print("armtrack")
    return 0
