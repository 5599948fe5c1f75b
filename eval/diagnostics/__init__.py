"""Probes of a trained policy, one module each (``python -m eval.diagnostics.<name>``); see README.md."""
