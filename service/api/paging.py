"""Cursor paging of listings (``?limit=&cursor=`` → ``next_cursor``): a cursor is the opaque,
URL-safe encoding of the sort key ``(created_at, id)`` of the last item of a page; the next
page starts strictly after it, so items created meanwhile never shift a page."""

from __future__ import annotations

import base64
import json

from service.errors import InvalidInput


def encode_cursor(created_at: float, item_id: str) -> str:
    raw = json.dumps([float(created_at), str(item_id)], separators=(",", ":")).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_cursor(cursor: str | None) -> tuple[float, str] | None:
    if not cursor:
        return None
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        created, item_id = json.loads(raw)
        if not isinstance(item_id, str) or not isinstance(created, (int, float)):
            raise ValueError
        return float(created), item_id
    except (ValueError, TypeError):
        raise InvalidInput("cursor is not one returned as next_cursor by this listing",
                           field="cursor") from None
