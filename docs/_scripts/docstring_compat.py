"""Read gaffer's Markdown-flavoured docstrings as reStructuredText (an `autodoc-process-docstring` hook).

gaffer's docstrings follow the Google style that napoleon parses, but their inline markup is Markdown's,
as in the rest of the repository: `x` for code, `- ` lists straight after a sentence, pipe tables, |x|
for an absolute value, code glued to text (`W2CBlender`s, `s`^2). In reST those mean something else or
are errors. This hook runs before napoleon and rewrites exactly these constructs, leaving everything
else alone:

- a single-backtick span becomes an inline literal (double backticks), with an escaped space where reST
  needs a boundary that Markdown does not (`x`s -> ``x``\\ s); roles (:py:func:`x`) and hyperlink
  references (`x`_) are untouched;
- a bullet list that follows a paragraph line, a nested list, and a paragraph right after a list get the
  blank lines reST requires around them;
- a fenced code block (```) becomes a literal block;
- a pipe table (header row, |---| separator row, body rows) becomes a `list-table` directive;
- a `|` outside code becomes `\\|` (reST reads |x| as a substitution reference);
- a Markdown indented code block (a blank line, then lines indented 4 or more past the paragraph above)
  becomes a literal block;
- a data/attribute/property docstring whose first line is prose containing a colon is re-wrapped so that the colon
  starts line 2 (the same paragraph); napoleon would read "text before the colon" as the attribute's type.

Lines of doctests (from `>>>` to the next blank line) and of literal blocks (after a line ending in `::`)
are never changed. The functions are pure, so the rules are easy to test:
`python docs/_scripts/docstring_compat.py` runs the self-checks at the bottom.
"""

import re

_CODE = re.compile(r"(?<![`:\w\\])`(?!`)([^`\n]+?)`(?![`_])")
# reST: an inline markup start-string must follow whitespace or one of these, an end-string must be
# followed by whitespace or one of these (docutils "inline markup recognition rules", simplified).
_BEFORE_OK = set(" \t'\"([{<-/:") | {""}
_AFTER_OK = set(" \t'\")]}>-/:.,;!?\\") | {""}
_BULLET = re.compile(r"^(\s*)[-*+] \S")
_TABLE_ROW = re.compile(r"^\s*\|.*\|\s*$")
_TABLE_SEP = re.compile(r"^\s*\|(\s*:?-{3,}:?\s*\|)+\s*$")


def _inline(text: str) -> str:
    """Backtick spans -> inline literals with reST-safe boundaries; `|` outside code escaped."""
    out, pos = [], 0
    for m in _CODE.finditer(text):
        before = text[m.start() - 1] if m.start() > 0 else ""
        after = text[m.end()] if m.end() < len(text) else ""
        chunk = text[pos : m.start()].replace("|", "\\|")
        out.append(chunk)
        out.append(
            ("" if before in _BEFORE_OK else "\\ ")
            + f"``{m.group(1).strip()}``"
            + ("" if after in _AFTER_OK else "\\ ")
        )
        pos = m.end()
    out.append(text[pos:].replace("|", "\\|"))
    return "".join(out)


def _table(rows: list[str], indent: str) -> list[str]:
    """Pipe-table lines (separator removed) -> a list-table directive."""
    cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
    out = [f"{indent}.. list-table::", f"{indent}   :header-rows: 1", ""]
    for row in cells:
        for k, cell in enumerate(row):
            out.append(f"{indent}   {'* -' if k == 0 else '  -'} {_inline(cell) or '..'}")
    out.append("")
    return out


def convert(lines: list[str], what: str = "") -> list[str]:
    """The rewritten docstring lines (see the module docstring for the rules)."""
    out: list[str] = []
    i, n = 0, len(lines)
    in_doctest, literal_indent = False, None
    while i < n:
        line = lines[i]
        stripped = line.strip()
        indent = line[: len(line) - len(line.lstrip())]
        if literal_indent is not None:
            if stripped and len(indent) <= literal_indent:
                literal_indent = None
            else:
                out.append(line)
                i += 1
                continue
        if stripped.startswith(">>>"):
            in_doctest = True
        if in_doctest:
            out.append(line)
            in_doctest = bool(stripped)
            i += 1
            continue
        if stripped.startswith("```"):
            # A fenced code block: a "::" literal block of the lines up to the closing fence.
            j = i + 1
            body = []
            while j < n and not lines[j].strip().startswith("```"):
                body.append(lines[j])
                j += 1
            if out and out[-1].strip():
                out.append("")
            out += [f"{indent}::", ""] + [
                f"{indent}    {b[len(indent) :]}" if b.strip() else "" for b in body
            ]
            out.append("")
            i = j + 1
            continue
        block_indent = _code_block_indent(out, len(indent)) if stripped else None
        if block_indent is not None:
            # Markdown's indented code block: a "::" paragraph (which renders as nothing) makes it
            # a reST literal block, copied verbatim up to the next line at the paragraph's indent.
            out += [" " * block_indent + "::", "", line]
            literal_indent = block_indent
            i += 1
            continue
        if _TABLE_ROW.match(line) and i + 1 < n and _TABLE_SEP.match(lines[i + 1]):
            rows = [line]
            j = i + 2
            while j < n and _TABLE_ROW.match(lines[j]):
                rows.append(lines[j])
                j += 1
            if out and out[-1].strip():
                out.append("")
            out += _table(rows, indent)
            i = j
            continue
        if stripped and out and out[-1].strip():
            prev = out[-1]
            prev_indent = len(prev) - len(prev.lstrip())
            item = _nearest_item_indent(out)
            if _BULLET.match(line):
                # A list starts after a paragraph line, a nested list starts inside an item, or a
                # nested list ends: reST wants a blank line in each case (not between siblings).
                if (item is None and prev_indent <= len(indent)) or (
                    item is not None and item != len(indent)
                ):
                    out.append("")
            elif item is not None and len(indent) <= item:
                # A paragraph right after a list (not the item's own continuation line).
                out.append("")
        out.append(_inline(line))
        if stripped.endswith("::"):
            literal_indent = len(indent)
        i += 1
    if what in ("data", "attribute", "property") and out:
        head = out[0]
        colon = head.find(": ")
        if colon > 0 and " " in head[:colon].strip() and "`" not in head[:colon]:
            # napoleon reads only the first line for "type: description"; move the colon to line 2
            # (same paragraph, same rendered text).
            k = head.rfind(" ", 0, colon)
            out[0:1] = [head[:k], head[k + 1 :]]
    return out


def _code_block_indent(out: list[str], indent: int) -> int | None:
    """The paragraph's indentation when a line at `indent` opens a Markdown indented code block, else None.

    That is: a blank line, then a line indented at least 4 more than the last paragraph line above it
    (which is neither a doctest line, nor a bullet item, nor a line ending in "::").
    """
    if not out or out[-1].strip():
        return None
    prev = next((p for p in reversed(out) if p.strip()), None)
    if prev is None:
        return None
    prev_indent = len(prev) - len(prev.lstrip())
    text = prev.strip()
    if indent < prev_indent + 4 or text.endswith("::") or text.startswith((">>>", "...")):
        return None
    if _BULLET.match(prev) or text.startswith(".."):
        return None
    return prev_indent


def _nearest_item_indent(out: list[str]) -> int | None:
    """Indentation of the closest bullet item above (back to a blank line), or None."""
    for prev in reversed(out):
        if not prev.strip():
            return None
        m = _BULLET.match(prev)
        if m:
            return len(m.group(1))
    return None


def process_docstring(app, what, name, obj, options, lines) -> None:
    """`autodoc-process-docstring` handler: rewrite `lines` in place."""
    lines[:] = convert(list(lines), what)


if __name__ == "__main__":
    assert _inline("a `x` b") == "a ``x`` b"
    assert _inline("`W2CBlender`s") == "``W2CBlender``\\ s"
    assert _inline("`supersample`^2") == "``supersample``\\ ^2"
    assert _inline(":py:func:`f` and `g`_") == ":py:func:`f` and `g`_"
    assert _inline("|v| > 1 and `a|b`") == "\\|v\\| > 1 and ``a|b``"
    assert convert(["Intro:", "- one", "- two"]) == ["Intro:", "", "- one", "- two"]
    assert convert(["- one", "  more", "- two"]) == ["- one", "  more", "- two"]
    assert convert(["Example:", "    >>> f(`x`)", "    `y`", "", "`z`"]) == [
        "Example:",
        "    >>> f(`x`)",
        "    `y`",
        "",
        "``z``",
    ]
    assert convert(["| a | b |", "|---|---|", "| `c` | d |"])[0] == ".. list-table::"
    assert convert(["The pose: camera right"], "data") == ["The", "pose: camera right"]
    assert convert(["int: the count"], "data")[0] == "int: the count"
    assert convert(["Usage:", "", "    cmd --flag", "      (note)", "", "Text"]) == [
        "Usage:",
        "",
        "::",
        "",
        "    cmd --flag",
        "      (note)",
        "",
        "Text",
    ]
    assert convert(["- item", "", "      more"])[-1] == "      more"
    assert convert(["- a:", "  - b", "  - c", "- d", "Text"]) == [
        "- a:",
        "",
        "  - b",
        "  - c",
        "",
        "- d",
        "",
        "Text",
    ]
    assert convert(["Tree:", "", "```", "a/", "  b  # `c`", "```", "After"]) == [
        "Tree:",
        "",
        "::",
        "",
        "    a/",
        "      b  # `c`",
        "",
        "After",
    ]
    assert _inline("`EVENT ` then") == "``EVENT`` then"
    print("docstring_compat: self-checks passed")
