"""Evaluation of ActionFlow, run as modules from the repository root (``python -m eval.paper ...``).

``paper/`` is the paper harness (one resumable matrix of cells over the standard LeRobot commands), ``bench/``
the benchmarks, ``diagnostics/`` the probes of a trained policy; ``provenance`` says which code, packages and
machine made a result; ``results/`` holds the committed tables, plots and cells. Every script writes under
``outputs/`` unless told ``--out`` / ``--results-dir``: nothing here writes into the source tree by default.
"""
