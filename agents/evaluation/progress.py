"""Progress of the main job's long loops (every tracker on every suite, then the figures), on stderr.

The bar names the item now running (not the one just finished) and estimates the time left from what has been
measured: items have a weight (their expected cost in some unit, e.g. the suite's looks) and a kind (items of one
kind cost about the same per unit, e.g. one tracker), so a slow tracker's first suite does not make every later
item look slow, and no time is guessed before anything has been measured (:func:`remaining_s`).

On a terminal the bar is :mod:`rich`'s live bar (its clock runs while an item runs); otherwise (a log file, CI,
rich not installed) one plain line per item."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress", "remaining_s", "format_duration"]


def remaining_s(items, seconds, current=None, current_elapsed_s=0.0):
    """Expected seconds left, or None while no item has finished (no rate measured yet).

    Args:
        items: list of ``(label, weight, kind)``.
        seconds: ``{index: seconds}`` of the finished items, in the order they finished.
        current: index of the running item (its expected cost minus ``current_elapsed_s`` is counted, at least 0).
    Each item not finished costs ``weight x rate``: the rate (seconds per unit weight) of the last finished item
    of its kind (a kind's first item may include one-time costs such as compilation), else the mean rate of the
    kinds measured so far."""
    rates = {}
    for i, s in seconds.items():
        _, w, kind = items[i]
        rates[kind] = s / max(float(w), 1e-12)
    if not rates:
        return None
    mean = sum(rates.values()) / len(rates)
    left = 0.0
    for i, (_, w, kind) in enumerate(items):
        if i in seconds:
            continue
        est = float(w) * rates.get(kind, mean)
        if i == current:
            est = max(est - current_elapsed_s, 0.0)
        left += est
    return left


def format_duration(s):
    """``"42 s"``, ``"3 min 5 s"``, ``"1 h 02 min"``."""
    s = int(round(s))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s" if s < 600 else f"{round(s / 60)} min"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


class Progress:
    """A bar over ``items`` (``(label, weight, kind)``) run one after another: :meth:`start` before an item runs,
    :meth:`done` after it, :meth:`close` at the end (prints ``"<title>: N items in T"``).

    Args:
        title: what the loop is (``"evaluate"``, ``"figures"``).
        enabled: False draws and prints nothing.
        live: True: rich's live bar; False: plain lines; None (default): live if the stream is a terminal and
            rich is installed."""

    def __init__(self, title, items, enabled=True, stream=None, live=None):
        self.title, self.items, self.enabled = title, list(items), bool(enabled)
        self.stream = stream or sys.stderr
        self.seconds = {}
        self.current, self._t_item, self._t0 = None, None, time.perf_counter()
        self._rich = None
        if not self.enabled:
            return
        if live is None:
            live = bool(getattr(self.stream, "isatty", lambda: False)())
        if live:
            try:
                self._rich = _RichBar(self)
            except ImportError:
                self._rich = None

    def eta_text(self):
        """``"~3 min left"``, or ``""`` before anything has been measured."""
        now = time.perf_counter()
        el = 0.0 if self._t_item is None else now - self._t_item
        left = remaining_s(self.items, self.seconds, self.current, el)
        return "" if left is None else f"~{format_duration(left)} left"

    def start(self, i):
        """Item ``i`` starts now (the bar shows its label)."""
        self.current, self._t_item = i, time.perf_counter()
        if not self.enabled:
            return
        label = self.items[i][0]
        if self._rich is not None:
            self._rich.show(label)
        else:
            eta = self.eta_text()
            print(f"[{len(self.seconds) + 1}/{len(self.items)}] {label} ... "
                  f"({format_duration(time.perf_counter() - self._t0)} so far{', ' + eta if eta else ''})",
                  file=self.stream, flush=True)

    def done(self, i=None):
        """Item ``i`` (default: the running one) has finished."""
        i = self.current if i is None else i
        t_from = self._t_item if i == self.current and self._t_item is not None else time.perf_counter()
        self.seconds[i] = time.perf_counter() - t_from
        if i == self.current:
            self.current, self._t_item = None, None
        if self._rich is not None:
            self._rich.advance(self.items[i][1])

    def close(self):
        """End the bar and say how long the loop took."""
        if not self.enabled:
            return
        if self._rich is not None:
            self._rich.stop()
            self._rich = None
        print(f"{self.title}: {len(self.seconds)} of {len(self.items)} items in "
              f"{format_duration(time.perf_counter() - self._t0)}", file=self.stream, flush=True)


class _RichBar:
    """rich's live bar for :class:`Progress` (description, bar, count, elapsed clock and the estimate)."""

    def __init__(self, owner):
        from rich.console import Console
        from rich.progress import BarColumn, ProgressColumn, TextColumn, TimeElapsedColumn
        from rich.progress import Progress as RichProgress
        from rich.text import Text

        class Eta(ProgressColumn):
            def render(self, task):
                return Text(owner.eta_text(), style="progress.remaining")

        self.owner = owner
        self.bar = RichProgress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[count]}"),
                                TimeElapsedColumn(), Eta(), console=Console(file=owner.stream), transient=True,
                                refresh_per_second=4)
        total = sum(float(w) for _, w, _ in owner.items) or 1.0
        self.task = self.bar.add_task(owner.title, total=total, count="")
        self.bar.start()

    def show(self, label):
        o = self.owner
        self.bar.update(self.task, description=f"{o.title}: {label}",
                        count=f"{len(o.seconds) + 1}/{len(o.items)}")

    def advance(self, weight):
        self.bar.advance(self.task, float(weight))

    def stop(self):
        self.bar.stop()
