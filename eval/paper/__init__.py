"""The paper benchmark: the paper's three experiments as one resumable matrix of cells, run by
``python -m eval.paper <experiment>`` (``__main__``) through LeRobot's standard commands.

``profiles`` says what runs, ``plan`` turns a profile into datasets, trainings and cells, ``commands`` spells
each stage's command line, ``run`` runs a cell and writes its JSON, ``report`` rebuilds tables and plots from
the JSON, ``replay`` is the light-bulb experiment's replay baseline (``python -m eval.paper.replay``).
"""
