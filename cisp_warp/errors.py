"""The project's one exception type for bad input, and its warning type."""

from __future__ import annotations


class SceneError(ValueError):
    """Bad input: a scene file, prim or parameter the renderer cannot use.

    The message always names what to look at: the file, the prim path (or parameter) and the reason.
    """

    def __init__(self, reason: str, file: str | None = None, prim: str | None = None):
        self.reason = reason
        self.file = file
        self.prim = prim
        where = []
        if file:
            where.append(f"file '{file}'")
        if prim:
            where.append(f"prim '{prim}'")
        super().__init__(f"{', '.join(where)}: {reason}" if where else reason)


class SceneWarning(UserWarning):
    """Something in the input is ignored or approximated (an unsupported light, a texture, a degenerate face)."""
