"""Commands built on the policy and the simulation suite: dataset recording (``actionflow-record``), the rerun
rollout recording (``python -m lerobot_actionflow.tools.visualize``) and the main job
(``python -m lerobot_actionflow.tools.demo``)."""
