"""What a command has to say, as data: lines, tables and warnings in order (a
:class:`Summary`), built by the library's workflows (:mod:`pkmcal.workflows`) and rendered by
any front end (the CLI's console, a notebook, a log) without knowing which command made it.

A cell or line is plain text: nothing in it is read as markup (Klipper's ``[bed_mesh
default]`` stays as written). A cell may carry a style for emphasis (``("yes", "green")``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Summary", "SummaryTable", "RawText"]


@dataclass
class SummaryTable:
    """A table of text cells.

    Attributes
    ----------
    columns : tuple of str
        The column headings (empty strings and ``header=False`` for a two-column
        label / value list).
    rows : list of tuple
        The rows, each a cell per column: a str, or ``(text, style)`` with a rich style name
        (``"green"``) the renderer may show.
    title : str or None
        Shown above the table.
    justify : dict
        Column index -> ``"left"`` / ``"right"`` (default left).
    header : bool
        Whether the headings are shown.
    """

    columns: tuple[str, ...]
    rows: list[tuple] = field(default_factory=list)
    title: str | None = None
    justify: dict[int, str] = field(default_factory=dict)
    header: bool = True

    def add_row(self, *cells) -> None:
        """Append a row (as many cells as columns; missing ones are empty)."""
        if len(cells) > len(self.columns):
            raise ValueError(f"{len(cells)} cells for {len(self.columns)} columns")
        self.rows.append(tuple(cells) + ("",) * (len(self.columns) - len(cells)))


@dataclass
class RawText:
    """Text written as it is (a JSON document on stdout, a CSV): no wrapping, no markup, and
    no newline added when it ends in one."""

    text: str


@dataclass
class Summary:
    """A command's output for a person, in order: lines (:class:`str`), tables
    (:class:`SummaryTable`) and raw text (:class:`RawText`); warnings are said after them,
    each once, then errors (why a run that wrote its outputs did not succeed, with
    ``exit_code`` 1); ``exit_code`` is the command's (0: done; 1: ran and did not succeed)."""

    blocks: list = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    exit_code: int = 0
    errors: list[str] = field(default_factory=list)

    def line(self, text: str) -> None:
        """Append a line of plain text."""
        self.blocks.append(str(text))

    def table(self, *columns: str, title: str | None = None, justify=None,
              header: bool = True) -> SummaryTable:
        """Append a table and return it (to add its rows)."""
        table = SummaryTable(tuple(columns), title=title, justify=dict(justify or {}),
                             header=header)
        self.blocks.append(table)
        return table

    def pairs(self, title: str | None = None) -> SummaryTable:
        """Append a label / value table without headings and return it."""
        return self.table("", "", title=title, header=False)

    def raw(self, text: str) -> None:
        """Append text written as it is."""
        self.blocks.append(RawText(text))

    def warn(self, text: str) -> None:
        """A warning, said once after the blocks."""
        if text not in self.warnings:
            self.warnings.append(text)

    def error(self, text: str) -> None:
        """Why the command did not succeed, said after the warnings; sets ``exit_code`` 1."""
        self.errors.append(text)
        self.exit_code = max(self.exit_code, 1)

    def text(self) -> str:
        """The blocks as plain text (tables as tab-separated lines), for logs and tests."""
        out = []
        for block in self.blocks:
            if isinstance(block, SummaryTable):
                if block.title:
                    out.append(block.title)
                if block.header and any(block.columns):
                    out.append("\t".join(block.columns))
                out += ["\t".join(c if isinstance(c, str) else c[0] for c in r)
                        for r in block.rows]
            elif isinstance(block, RawText):
                out.append(block.text.rstrip("\n"))
            else:
                out.append(block)
        return "\n".join(out) + ("\n" if out else "")
