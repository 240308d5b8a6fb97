"""The two kinds of failure the master reports.

ConfigError: the user asked for something that cannot be run (bad system, bad
step size, bad option). The command line prints it as one line, exit status 2.
SimulationError: a run started and a component failed a step; it names the
component, the time and the reason.
"""


class ConfigError(ValueError):
    """Bad input: a system, option or file that cannot be run."""


class SimulationError(RuntimeError):
    """A component failed a step (status discard, error or fatal), or its initialization.

    Parameters
    ----------
    component : str
        The component's name.
    time : float
        Seconds: the start of the failed step (the start time for initialization).
    reason : str
        The component's reason.
    status : str
        ``discard``, ``error``, ``fatal`` or ``initialization``.
    trials : tuple of int
        Batch positions the component blamed; () means the whole batch.
    """

    def __init__(self, component: str, time: float, reason: str, status: str = "error", trials=()):
        super().__init__(f"{component} failed the step at t = {time:.6g} s ({status}): {reason}")
        self.component, self.time, self.reason, self.status = component, time, reason, status
        self.trials = tuple(trials)  # batch positions the component blamed; () = the whole batch

    def __reduce__(self):  # pickles whole, e.g. out of a worker process
        return type(self), (self.component, self.time, self.reason, self.status, self.trials), self.__dict__


MAX_WORD = 200    # characters of one run without spaces in an error line (a value echoed): longer is cut, "..."
MAX_LINE = 2000   # characters of the whole line: a longer one keeps its head and its end, "..." between


def one_line(message) -> str:
    """``message`` as the one line an error is printed as: whitespace collapsed, and cut to a bounded length,
    so that a huge value echoed in it (a 1 MB string in a configuration) leaves a line that can be read: each
    run of more than MAX_WORD characters without a space cut to its first MAX_WORD and "...", and a line of
    more than MAX_LINE characters to its head and its end (the reason, at the end, stays)."""
    line = " ".join(word if len(word) <= MAX_WORD else word[:MAX_WORD] + "..." for word in str(message).split())
    if len(line) <= MAX_LINE:
        return line
    end = MAX_LINE // 4
    return line[:MAX_LINE - end - 5] + " ... " + line[-end:]
