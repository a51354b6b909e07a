"""Reading the text files users give vpsim: UTF-8 (with or without BOM) only, any newline convention.

Every failure is the caller's error class with one line naming the file (and the line where it applies):
missing file, dangling symbolic link, symbolic-link loop, a folder, a FIFO or a device instead of a file
(refused before it is opened: opening a FIFO blocks), a file too large, binary (NUL bytes), UTF-16 or other
non-UTF-8 text; for JSON also nesting beyond Python's recursion limit.
"""

from __future__ import annotations

import errno
import json
import stat
from pathlib import Path
from typing import Any

MAX_TEXT_BYTES = 16 * 1024 * 1024  # a parameter file, sweep spec or gear schedule larger than this is refused


MAX_PATH_CHARS = 4096  # PATH_MAX on Linux


def check_path(name: Any, error: type[Exception], what: str = "file") -> Path:
    """``name`` as a Path, or one-line ``error`` if it cannot name a file (NUL character, too long)."""
    text = str(name)
    if "\x00" in text:
        raise error(f"{short_name(text)}: a {what} name cannot hold a NUL character")
    if len(text) > MAX_PATH_CHARS:
        raise error(
            f"{short_name(text)}: a {what} name of {len(text)} characters, more than {MAX_PATH_CHARS}"
        )
    return Path(name)


def printable(text: Any) -> str:
    """``text`` with every control character (newline, ESC, NUL, DEL, ...) written as an escape: safe for
    one line on a terminal or in a file's comment, whatever a record held."""
    return "".join(
        ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in str(text)
    )


def short_name(text: Any, limit: int = 120) -> str:
    """A file name cut for a one-line message."""
    s = str(text).replace("\x00", "\\0")
    return s if len(s) <= limit else s[: limit - 3] + "..."


def check_regular_file(path: Any, error: type[Exception], what: str = "file") -> Path:
    """``path`` as a Path, after checking (without opening it) that it names a regular file: one-line
    ``error`` for a missing file, a dangling link, a link loop, a folder, or a FIFO or a device (``/dev/zero``
    never ends, a FIFO blocks the reader until someone writes). For readers that open files themselves
    (pandas)."""
    path = check_path(path, error, what)
    try:
        st = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            raise error(f"{path}: dangling symbolic link (its target does not exist)") from None
        raise error(f"{path}: no such file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error(f"{path}: symbolic link loop (too many levels of symbolic links)") from None
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a folder, expected a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: not a regular file (a FIFO, socket or device), expected a {what}")
    return path


def read_json(path: Any, error: type[Exception], *, limit: int = MAX_TEXT_BYTES, what: str = "JSON file"):
    """The parsed JSON of a UTF-8 file (:func:`read_text`'s checks); one-line ``error`` for invalid JSON,
    ``NaN``/``Infinity`` (not JSON), or arrays and objects nested too deeply (Python's recursion limit)."""
    path = check_path(path, error, what)
    text = read_text(path, error, limit=limit, what=what)

    def no_constant(token: str) -> Any:
        raise error(f"{path}: {token} is not a JSON number")

    try:
        return json.loads(text, parse_constant=no_constant)
    except json.JSONDecodeError as exc:
        raise error(f"{path}:{exc.lineno}: not valid JSON ({exc.msg})") from None
    except RecursionError:
        raise error(f"{path}: not valid JSON (arrays or objects nested too deeply)") from None
    except ValueError as exc:  # an integer literal of more than 4300 digits
        if isinstance(exc, error):
            raise
        raise error(f"{path}: not valid JSON ({printable(exc)[:200]})") from None


def read_text(path: Path, error: type[Exception], *, limit: int = MAX_TEXT_BYTES, what: str = "file") -> str:
    """The text of a UTF-8 file (with or without BOM; CRLF/CR newlines become LF); one-line ``error``
    when it is missing, a folder, a symlink loop, unreadable, too large, binary or not UTF-8."""
    path = check_path(path, error, what)
    try:
        st = path.stat()
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError
        if not stat.S_ISREG(st.st_mode):  # a FIFO or a device would block or never end
            raise error(f"{path}: not a regular file (a FIFO, socket or device), expected a {what}")
        if st.st_size > limit:
            raise error(f"{path}: file is {st.st_size} bytes, more than the {limit}-byte limit for a {what}")
        with path.open("rb") as fh:
            raw = fh.read(limit + 1)
    except FileNotFoundError:
        if path.is_symlink():
            raise error(f"{path}: dangling symbolic link (its target does not exist)") from None
        raise error(f"{path}: no such file") from None
    except IsADirectoryError:
        raise error(f"{path}: is a folder, expected a {what}") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error(f"{path}: symbolic link loop (too many levels of symbolic links)") from None
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    if len(raw) > limit:
        raise error(f"{path}: file is larger than the {limit}-byte limit for a {what}")
    return decode_text(raw, path, error)


def decode_text(raw: bytes, where: Any, error: type[Exception]) -> str:
    """``raw`` decoded as UTF-8 (a BOM is dropped), newlines normalised; one-line ``error`` otherwise."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise error(f"{where}: not a text file in UTF-8 (UTF-16 byte-order mark); save it as UTF-8")
    nul = raw.find(b"\x00")
    if nul >= 0:
        line = raw.count(b"\n", 0, nul) + 1
        raise error(f"{where}:{line}: not a text file (NUL byte: binary data), expected UTF-8 text")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise error(
            f"{where}:{line}: not a text file in UTF-8 (byte 0x{raw[exc.start]:02x} at offset {exc.start}); "
            "save the file as UTF-8"
        ) from None
    return text.replace("\r\n", "\n").replace("\r", "\n")


__all__ = [
    "MAX_TEXT_BYTES",
    "check_path",
    "check_regular_file",
    "decode_text",
    "read_json",
    "read_text",
    "short_name",
]


# where a quote opened is searched for in files of at most so many lines, re-parsing at most so much text
TOML_OPEN_SEARCH_LINES = 5000
TOML_OPEN_SEARCH_BYTES = 1024 * 1024  # (Python parses TOML at about 1-2 MB/s)


def toml_error(exc: Exception, text: str) -> str:
    """``exc`` (a ``tomllib.TOMLDecodeError``) as a one-line reason. Python's parser reports a quote,
    string or array left open "at end of document"; the line it opens on is then found as the line after
    the longest run of whole lines that parses (re-parsing from the end; in a file of at most
    :data:`TOML_OPEN_SEARCH_LINES` lines, within a bounded amount of text: else the parser's words)."""
    import tomllib

    msg = str(exc)
    if not msg.endswith("(at end of document)"):
        return msg
    lines = text.splitlines(keepends=True)
    if len(lines) > TOML_OPEN_SEARCH_LINES:
        return msg
    spent = 0
    for k in range(len(lines) - 1, -1, -1):
        head = "".join(lines[:k])
        spent += len(head)
        if spent > TOML_OPEN_SEARCH_BYTES:
            break
        try:
            tomllib.loads(head)
        except tomllib.TOMLDecodeError as e:
            if str(e).endswith("(at end of document)"):
                continue
        except RecursionError:
            break
        return f"{msg[: -len('(at end of document)')]}(at line {k + 1}, where it opens and is never closed)"
    return msg
