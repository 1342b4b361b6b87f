"""The one error type users see: a one-line message that names the fix."""


class WorldagentError(ValueError):
    """Bad input at an API boundary; the message says what is wrong and how to fix it."""
