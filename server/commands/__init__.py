"""One module per ``armtrack`` sub-command: ``HELP`` (one line for ``armtrack --help``),
``DESCRIPTION``, ``add_arguments(parser)`` and ``run(args) -> int``.

Module level imports only the standard library and light names (``estimator.errors``,
``estimator.body``, :mod:`.choices`): ``armtrack --help`` builds every command's parser.
numpy, scipy, numba, pyarrow, sqlalchemy, fastapi, uvicorn are imported inside ``run``.
"""
