"""Benchmarks, one module each (``python -m eval.bench.<name>``); README.md says what each measures, how to
rerun it and which file under eval/results/ holds its committed result."""
