"""One located warning per cause, not per line: a reason for a note that several lines of a
``.zmx`` file may share (:class:`Cause`), and how its items are listed (:func:`listed`).

Its own module so that the readers of single records (:mod:`.zmx_scbd`, which the parser itself
imports) can state their causes; :class:`~.zmx_parse.Locator` groups the notes.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["MAX_NOTE_ITEMS", "Cause", "listed", "literal"]

#: the most items (glass names, surfaces) one grouped note names (the rest counted)
MAX_NOTE_ITEMS = 4


def listed(items, cap: int = MAX_NOTE_ITEMS) -> str:
    """``"'A', 'B', 'C'"``: ``items`` joined, the first ``cap`` named and the rest counted
    (``"'A', 'B', 'C', 'D' and 12 more"``)."""
    items = list(items)
    shown = ", ".join(items[:cap])
    return f"{shown} and {len(items) - cap} more" if len(items) > cap else shown


def literal(text) -> str:
    """``text`` as literal text of a :class:`Cause` template (its braces doubled)."""
    return str(text).replace("{", "{{").replace("}", "}}")


@dataclass(frozen=True)
class Cause:
    """One reason for a note that several lines of a file may share (a glass read from its
    six-digit code, a fixed ``DIAM`` that does not clip): :meth:`~.zmx_parse.Locator.note_each`
    keeps one note per line, and :meth:`~.zmx_parse.Locator.warn_notes` issues one warning per
    cause naming every line.  ``one`` is the message for one item (``{item}``: a glass name,
    ``"SURF 3"``, the same on every line; ``{detail}``: what is particular to it), ``many`` for
    several (``{n}``: how many, ``{items}``: them, capped by :func:`listed`, each as the note
    names it in a list: its ``shown`` text, which may carry its numbers); both keep the choice
    made and the option that flips it.  Two causes are one when their texts are equal (so a text that depends on
    the file, such as the catalogue to give, keeps such files apart)."""

    one: str
    many: str

    def message(self, items: dict) -> str:
        """The warning's text for the distinct ``items`` (item -> ``(detail, shown)``, in the
        order first met; ``shown`` ``None``: the item itself)."""
        if len(items) == 1:
            item, (detail, _) = next(iter(items.items()))
            return self.one.format(item=item, detail=detail)
        return self.many.format(n=len(items), items=listed(i if s is None else s
                                                           for i, (_, s) in items.items()))
