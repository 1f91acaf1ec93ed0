"""Co-design of the vision loop: the camera mode, the tracker, the observer and the controller
chosen together against closed-loop performance (``pmspm codesign SPEC.yaml``, docs/codesign.md).

* ``spec``: the validated spec file (the design space, objectives, constraints, search and
  report settings).
* ``catalogue``: the trackers' latency, accuracy and re-detection, from seed 000 Table 1 and
  the tracking benchmark's result files.
* ``space``: a design (one point of the space), the seed's design, and the scenarios of a design.
* ``analysis``: the exact-delay margins of a design (critical phase margin, delay headroom).
* ``evaluate``: the Monte-Carlo evaluation over seeds on the batched engine, with intervals.
* ``search``: the optuna study (NSGA-II or TPE, SQLite by default, resumable, shareable).
* ``report``: the Pareto front, the table of non-dominated designs, the recommended design
  beside the seed's, and the image-in-the-loop check of the recommended design.
"""
