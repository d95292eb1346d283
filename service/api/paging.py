"""Cursor paging of listings (``?limit=&cursor=`` → ``next_cursor``): a cursor is a position in
the listing's order, the sort key ``(created_at, id)`` of the last item of a page written as
``<created_at>~<id>`` (URL-safe); the next page starts strictly after it, so items created
meanwhile never shift a page. Every value of the cursor's pattern is a position (a page,
maybe empty), so the spec states all there is to know: clients pass back ``next_cursor``."""

from __future__ import annotations

from decimal import Decimal
from typing import Annotated

from fastapi import Query

# created_at in plain decimal notation (an exact float), then the item's id
# (domains: lowercase hex; jobs: letters, digits, '_' and '-')
CURSOR_PATTERN = r"^[0-9]{1,20}(\.[0-9]{1,40})?~[0-9A-Za-z_-]{1,64}$"

Cursor = Annotated[str | None, Query(pattern=CURSOR_PATTERN, max_length=128,
                                     description="`next_cursor` of the previous page")]


def encode_cursor(created_at: float, item_id: str) -> str:
    # repr round-trips the float exactly; Decimal writes it without an exponent
    return f"{Decimal(repr(float(created_at))):f}~{item_id}"


def decode_cursor(cursor: str | None) -> tuple[float, str] | None:
    """The position a cursor names (the route's ``Cursor`` query checked its pattern)."""
    if not cursor:
        return None
    created, item_id = cursor.split("~", 1)
    return float(created), item_id
