"""ActionFlow for LeRobot: SE(3) flow matching with an SE(3) Invariant Transformer.

Importing this package registers the policy type ``actionflow`` and the environment type ``actionflow``
(the gym_actionflow tasks) with LeRobot. LeRobot imports it first thing in ``lerobot-train`` and
``lerobot-eval`` (plugin discovery), so it is also where the torchcodec notice below is shortened.

Without LeRobot installed the package still imports, so that ``lerobot_actionflow.core`` (the policy in plain
torch) and ``lerobot_actionflow.schema`` can be used alone; the LeRobot-facing names then raise an
ImportError saying what is missing.
"""

import logging

try:
    import lerobot  # noqa: F401
except ImportError as _err:
    _LEROBOT_ERROR: ImportError | None = _err
else:
    _LEROBOT_ERROR = None

__all__ = ["ActionFlowConfig", "ActionFlowPolicy", "make_actionflow_pre_post_processors"]
__version__ = "0.1.0"

if _LEROBOT_ERROR is not None:

    def __getattr__(name: str):
        if name in __all__:
            raise ImportError(
                f"lerobot_actionflow.{name} needs LeRobot, which cannot be imported ({_LEROBOT_ERROR}); "
                "install it with `pip install 'lerobot>=0.6.1,<0.7'` "
                "(lerobot_actionflow.core works without it)"
            ) from _LEROBOT_ERROR
        raise AttributeError(f"module 'lerobot_actionflow' has no attribute {name!r}")

else:
    from lerobot_actionflow import env_config as _env_config  # noqa: F401  (registers --env.type=actionflow)
    from lerobot_actionflow.configuration_actionflow import ActionFlowConfig
    from lerobot_actionflow.modeling_actionflow import ActionFlowPolicy
    from lerobot_actionflow.processor_actionflow import make_actionflow_pre_post_processors


class _TorchcodecNotice(logging.Filter):
    """Shorten LeRobot's warning that torchcodec cannot be loaded to one line, once per process.

    Without FFmpeg's shared libraries (torchcodec needs FFmpeg 4-8 from the system or conda; pip does not
    install them), LeRobot logs torchcodec's loading traceback, one page per FFmpeg version, each time it
    picks a default video backend, then decodes video with pyav: token datasets have no video, and pyav
    decodes the camera ones. Every other record of that logger passes unchanged.
    """

    MARKER = "'torchcodec' is installed but cannot be loaded"

    def __init__(self) -> None:
        super().__init__()
        self.shown = False

    def filter(self, record: logging.LogRecord) -> bool:
        if self.MARKER not in str(record.msg):
            return True
        if self.shown:
            return False
        self.shown = True
        record.msg = (
            "torchcodec cannot be loaded (no FFmpeg 4-8 shared libraries found?): LeRobot decodes video with "
            "pyav instead. `python -c 'import torchcodec'` shows the full error."
        )
        record.args = ()
        return True


_import_logger = logging.getLogger("lerobot.utils.import_utils")
if not any(isinstance(f, _TorchcodecNotice) for f in _import_logger.filters):
    _import_logger.addFilter(_TorchcodecNotice())
