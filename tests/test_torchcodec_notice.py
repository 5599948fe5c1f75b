"""Without a system FFmpeg, every LeRobot command printed torchcodec's loading traceback (a page per FFmpeg
version); with the plugin imported, a user sees one line at most."""

import logging

from lerobot.utils.import_utils import get_safe_default_video_backend

import lerobot_actionflow  # installs the filter, as LeRobot's plugin discovery does)

LOGGER = "lerobot.utils.import_utils"


def test_torchcodec_failure_is_one_line_once(caplog):
    """LeRobot picks a default video backend several times per command; each failed torchcodec load used to
    log its whole traceback. Where torchcodec loads, nothing is logged at all."""
    for f in logging.getLogger(LOGGER).filters:
        if isinstance(f, lerobot_actionflow._TorchcodecNotice):
            f.shown = False  # as in a fresh process
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        for _ in range(3):
            get_safe_default_video_backend()
    notices = [r.getMessage() for r in caplog.records if "torchcodec" in r.getMessage()]
    assert len(notices) <= 1
    assert all("\n" not in m for m in notices), notices


def test_other_warnings_of_that_logger_pass_unchanged(caplog):
    """The filter must not hide LeRobot's other import warnings (a real missing package, say)."""
    message = "'foo' is required but not installed.\nInstall it with: pip install foo"
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        logging.getLogger(LOGGER).warning(message)
        logging.getLogger(LOGGER).warning(message)
    assert [r.getMessage() for r in caplog.records] == [message, message]
