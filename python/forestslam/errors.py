"""Exceptions raised by forestslam. The CLI prints any of them as one readable line."""


class ForestSlamError(Exception):
    """Base class of every error forestslam raises on purpose."""


class InputError(ForestSlamError):
    """An input file, topic, argument or configuration the user gave cannot be used."""


class ProcessingError(ForestSlamError):
    """An algorithm cannot produce a result from otherwise valid input."""


class Terminated(KeyboardInterrupt):
    """The process was asked to stop (SIGTERM); a job records it as `interrupted`."""
