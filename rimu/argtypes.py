"""argparse types for numeric options: finite, signed as asked, within stated limits.

A bad value is refused while the arguments are parsed, before any work or any file is
written: ``--duration nan``, ``--max-rate -300``, ``--turns 0`` fail with one line naming
the option, what it accepts and what it got (exit 2). Each factory returns a callable that
argparse uses as ``type=``; its ``__name__`` is what argparse would print as the type.

Examples
--------
>>> p.add_argument("--duration", type=positive_float(max_value=DAY_S))
>>> p.add_argument("--max-frames", type=positive_int())
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = [
    "DAY_S",
    "MAX_COUNT",
    "MAX_RUNS",
    "MAX_SAMPLES",
    "SEED_MAX",
    "bounded_float",
    "choice_or_url",
    "float_list",
    "nonnegative_float",
    "nonnegative_int",
    "positive_float",
    "positive_int",
    "probability",
    "refuse_ignored_options",
    "refuse_together",
]

DAY_S = 86_400.0
"""One day in seconds: the default upper limit of durations."""
MAX_COUNT = 1 << 40
"""Default upper limit of counts (frames, events)."""
SEED_MAX = 2**63 - 1
"""Largest random seed (numpy takes any non-negative integer; this keeps it one int64)."""
MAX_SAMPLES = 10_000_000
"""Most samples one simulated flight may hold in memory (about 28 h at 100 Hz)."""
MAX_RUNS = 100_000
"""Most Monte Carlo runs of one evaluation (each run's plan is held in memory)."""


def _show(v: float) -> str:
    return repr(float(v)) if isinstance(v, float) else str(v)


def _parse_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return x


def bounded_float(min_value: float | None = None, max_value: float | None = None, *,
                  min_open: bool = False, max_open: bool = False, min_abs: float = 0.0,
                  name: str = "number") -> Callable[[str], float]:
    """A finite float in ``[min_value, max_value]`` (open ends with ``min_open``/``max_open``).

    Parameters
    ----------
    min_value, max_value : float, optional
        Limits (None: unbounded on that side, but always finite).
    min_open, max_open : bool
        Exclude the limit itself.
    min_abs : float
        Smallest magnitude (a rotation angle of either sign but not near 0).
    name : str
        How the error message calls the value.
    """
    lo = "(" if min_open else "["
    hi = ")" if max_open else "]"
    rng = (f"{lo}{'-inf' if min_value is None else _show(min_value)}, "
           f"{'inf' if max_value is None else _show(max_value)}{hi}")

    def parse(text: str) -> float:
        x = _parse_float(text)
        bad = ((min_value is not None and (x < min_value or (min_open and x == min_value)))
               or (max_value is not None and (x > max_value or (max_open and x == max_value))))
        if bad:
            raise argparse.ArgumentTypeError(f"expected a {name} in {rng}, got {text}")
        if abs(x) < min_abs:
            raise argparse.ArgumentTypeError(f"expected a {name} of magnitude at least "
                                             f"{min_abs:g}, got {text}")
        return x

    parse.__name__ = name
    return parse


def probability() -> Callable[[str], float]:
    """A probability strictly between 0 and 1 (a test's significance level)."""
    return bounded_float(0.0, 1.0, min_open=True, max_open=True, name="probability")


def positive_float(max_value: float | None = None) -> Callable[[str], float]:
    """A finite float > 0 (and ≤ ``max_value``)."""
    return bounded_float(0.0, max_value, min_open=True, name="positive number")


def nonnegative_float(max_value: float | None = None) -> Callable[[str], float]:
    """A finite float ≥ 0 (and ≤ ``max_value``)."""
    return bounded_float(0.0, max_value, name="non-negative number")


def _int(min_value: int, max_value: int, name: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            x = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if not min_value <= x <= max_value:
            raise argparse.ArgumentTypeError(f"expected a {name} in [{min_value}, "
                                             f"{max_value}], got {text}")
        return x

    parse.__name__ = name
    return parse


def positive_int(max_value: int = MAX_COUNT) -> Callable[[str], int]:
    """A whole number ≥ 1 (and ≤ ``max_value``)."""
    return _int(1, max_value, "positive whole number")


def nonnegative_int(max_value: int = MAX_COUNT) -> Callable[[str], int]:
    """A whole number ≥ 0 (and ≤ ``max_value``)."""
    return _int(0, max_value, "non-negative whole number")


def float_list(min_value: float | None = None, max_value: float | None = None, *,
               count: int | None = None, sep: str = ",",
               name: str = "numbers") -> Callable[[str], tuple[float, ...]]:
    """A ``sep``-separated list of finite floats, each in ``[min_value, max_value]``.

    ``count`` fixes the number of values (None: any number, the empty text included).
    """
    one = bounded_float(min_value, max_value)

    def parse(text: str) -> tuple[float, ...]:
        parts = [x for x in text.split(sep) if x.strip()]
        if count is not None and len(parts) != count:
            raise argparse.ArgumentTypeError(f"expected {count} {name} separated by "
                                             f"{sep!r}, got {text!r}")
        try:
            return tuple(one(x.strip()) for x in parts)
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{exc} (in {text!r})") from None

    parse.__name__ = name
    return parse


def choice_or_url(choices: tuple[str, ...], scheme: str = "tcp",
                  name: str = "scheduler") -> Callable[[str], str]:
    """One of ``choices`` or an address ``SCHEME://HOST:PORT``."""
    def parse(text: str) -> str:
        if text in choices:
            return text
        head, sep, rest = text.partition("://")
        host, colon, port = rest.rpartition(":")
        if head == scheme and sep and host and colon and port.isdigit() \
                and 0 < int(port) < 65536:
            return text
        raise argparse.ArgumentTypeError(f"unknown {name} {text!r}; expected "
                                         f"{', '.join(choices)} or {scheme}://HOST:PORT")

    parse.__name__ = name
    return parse


def refuse_together(command: str, given: dict[str, object], option: str,
                    others: tuple[str, ...]) -> None:
    """Refuse ``option`` given with any of ``others`` in one line (``ConfigError``).

    ``given`` maps option names to their values; None (or False, or empty) means absent.
    Conflicting options are refused rather than one silently ignored.
    """
    from fdi.errors import ConfigError

    if given.get(option) in (None, False, "", [], ()):
        return
    clash = [o for o in others if given.get(o) not in (None, False, "", [], ())]
    if clash:
        raise ConfigError(f"{command}: {option} cannot be combined with {', '.join(clash)} "
                          f"(give one or the other)")


IGNORED_BESIDE: tuple[tuple[str, str], ...] = (
    ("false_alarms_per_hour", "thresholds"),
)
"""(option, other): ``--option`` means nothing when ``--other`` is given (the budget of
computed thresholds beside a thresholds file); both together are refused, in every command
that has them."""


def refuse_ignored_options(args: argparse.Namespace, command: str) -> None:
    """Refuse an option that another one given beside it would make meaningless
    (:data:`IGNORED_BESIDE`), rather than ignore it silently (``ConfigError``)."""
    ns = vars(args)
    for opt, other in IGNORED_BESIDE:
        if opt in ns and other in ns:
            refuse_together(command, {f"--{opt.replace('_', '-')}": ns[opt],
                                      f"--{other.replace('_', '-')}": ns[other]},
                            f"--{opt.replace('_', '-')}", (f"--{other.replace('_', '-')}",))
