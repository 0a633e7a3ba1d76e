"""The landmark store and its tools (SPEC section 6; docs/landmarks.md).

* ``landmark_db.store``: the SQLite file (``create_db``, ``open_db``, ``query_gate``);
* ``landmark_db.recognise``: ``Recogniser.from_path(path).process(frame, state)``;
* ``landmark_db.cli``: the ``landmark-db`` command.

Importing the package imports nothing heavy; the submodules load OpenCV.
"""
