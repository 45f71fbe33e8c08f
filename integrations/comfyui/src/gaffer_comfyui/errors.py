"""The pack's one error type: a bad node input, said in one line that names the input and the fix.

ComfyUI shows an exception's message in the node's error box, so every refusal is a `NodeInputError`
(a `ValueError`) raised before any work, and every expected failure of the gaffer libraries (a missing
file, an unreadable map, an empty mask) is re-raised as one, prefixed with the node's id, chained with
`from exc` so the library's own error stays in the traceback.
"""

__all__ = ["NodeInputError"]


class NodeInputError(ValueError):
    """A node input that cannot be used; the message names the node, the input and what to do."""
