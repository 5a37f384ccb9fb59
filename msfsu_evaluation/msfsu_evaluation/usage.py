"""The usage error shared by the evaluation commands (msfsu-eval-bag, msfsu-benchmark): exit code 2."""


class UsageError(ValueError):
    """The command line names something that cannot work; the message says what to change."""
