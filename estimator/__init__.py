"""armtrack's numerics: recordings, the arm model, joint angles, orientation filters.

Pure numpy/scipy: no web, no database. Radians inside, degrees only at the edges.
Quaternions are ``wxyz``.
"""
