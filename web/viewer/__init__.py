"""The live and replayed 3D arm for therapists, drawn with viser.

One loopback ``ViserServer`` per app (``host``); the FastAPI app hands out one-time viewer
grants and proxies viser's page and WebSocket behind the therapist's sign-in (``routes``,
``grants``, ``proxy``). Each connected viewer gets its own scene and panels (``view``:
``arm``, ``rom``, ``panels``), driven by the patient's live feed (``live``) or by a
stored session (``replay``).

Frames (``docs/spec/kinematics.md``): the scene's world is ENU with z up; the arm's nodes hang
under a thorax-frame node (X anterior, Y superior, Z right), origin at the sternal notch.
Positions in metres, angles shown in degrees.
"""
