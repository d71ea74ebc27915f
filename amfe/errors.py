"""The one exception type that reaches users: a clear message, no deep traceback."""


class AmfeError(Exception):
    """Bad input or an ill-posed problem; the message says what and how to fix it."""


def _list_items(items, limit=5):
    """Format the first `limit` items of a sequence, with a count of the rest."""
    items = list(items)
    head = ", ".join(str(x) for x in items[:limit])
    more = len(items) - limit
    return head + (f", ... ({more} more)" if more > 0 else "")
