"""The policy core: SE(3) geometry, the flow, the network and the model that joins them.

Plain torch: nothing here imports LeRobot or the simulator, so each piece can be used and tested alone. The
LeRobot-facing files (``configuration_actionflow``, ``modeling_actionflow``, ``processor_actionflow``) sit one
level up and build on it.
"""
