"""Every problem of a measured file in one message: readers collect them and raise once.

A reader checks what it can check independently (every row's cells, every dataset, every channel) and
adds each problem with its place; at the points where later checks need earlier ones to hold it calls
:meth:`Problems.check`, which raises one :class:`MeasuredDataError` listing them: the first
``MAX_LISTED`` (20) one per line, then how many more there are. One problem keeps the one-line form
``<file>: <place>: <problem>``.

Example::

    problems = Problems(path)
    for i, cell in enumerate(cells):
        with problems.collect():
            parse(cell)          # raises MeasuredDataError("<file>: line 3: ...")
    problems.check()
"""

from __future__ import annotations

from contextlib import contextmanager

__all__ = ["Problems", "MAX_LISTED", "MeasuredDataError"]

#: Problems listed one per line; the rest are counted.
MAX_LISTED = 20


class MeasuredDataError(ValueError):
    """A measured-FRF file that does not follow the format.

    The message starts with the file and names the place of each problem: a column, or a row as the user
    sees it in the file (for CSV the line number with the header as line 1; for Parquet the 1-based data
    row; for UFF the 1-based dataset and point). Several problems are listed one per line.
    """


class Problems:
    """Problems of one file, in the order found."""

    def __init__(self, source):
        self.source = str(source)
        self.items: list[str] = []

    def __len__(self) -> int:
        return len(self.items)

    def add(self, text: str) -> None:
        """Add ``"<place>: <problem>"`` (a leading ``"<file>: "`` is dropped)."""
        prefix = f"{self.source}: "
        self.items.append(text[len(prefix):] if text.startswith(prefix) else text)

    @contextmanager
    def collect(self):
        """Run a block; a :class:`MeasuredDataError` it raises becomes a problem and the reader goes on."""
        try:
            yield
        except MeasuredDataError as exc:
            self.add(str(exc))

    def message(self) -> str:
        if len(self.items) == 1:
            return f"{self.source}: {self.items[0]}"
        shown = self.items[:MAX_LISTED]
        rest = len(self.items) - len(shown)
        lines = [f"{self.source}: {len(self.items)} problems:"] + [f"  {item}" for item in shown]
        if rest:
            lines.append(f"  ... and {rest} more problem{'s' if rest > 1 else ''}")
        return "\n".join(lines)

    def check(self) -> None:
        """Raise one :class:`MeasuredDataError` listing every problem so far, if any."""
        if self.items:
            raise MeasuredDataError(self.message())
