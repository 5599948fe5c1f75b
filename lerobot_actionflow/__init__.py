"""ActionFlow for LeRobot: SE(3) flow matching with an SE(3) Invariant Transformer.

Importing this package registers the policy type ``actionflow`` and the environment type ``actionflow``
(the gym_actionflow tasks) with LeRobot.
"""

from lerobot_actionflow import env_config as _env_config  # noqa: F401  (registers --env.type=actionflow)
from lerobot_actionflow.configuration_actionflow import ActionFlowConfig
from lerobot_actionflow.modeling_actionflow import ActionFlowPolicy
from lerobot_actionflow.processor_actionflow import make_actionflow_pre_post_processors

__all__ = ["ActionFlowConfig", "ActionFlowPolicy", "make_actionflow_pre_post_processors"]
__version__ = "0.1.0"
