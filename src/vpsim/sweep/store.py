"""Append-only result store with point identities, so a sweep can stop anywhere and resume without loss.

On-disk layout of an output folder ``DIR``::

    DIR/sweep.json              what the sweep is: spec, format, columns (written once, checked on resume)
    DIR/.sweep.lock             held (flock) by the process writing DIR; a second writer is refused
    DIR/results.parquet/        Parquet format: a dataset folder, one part file per finished chunk
        part-<run_id>-<seq>.parquet
        .part-<...>.tmp         being written; renamed into place when complete, removed on resume
    DIR/results.csv             CSV format instead: one file, header + rows appended chunk by chunk

A Parquet file cannot be appended to, so every finished chunk becomes its own part file: written to a hidden
temporary name, flushed to disk (fsync), then renamed (atomic on POSIX). A part file is therefore complete or
absent; readers (this module, ``pandas.read_parquet(DIR / "results.parquet")``, pyarrow, dask) skip hidden
files. The CSV file is appended with one write per chunk followed by fsync; a write cut short by a kill leaves
a last line without its newline, which is cut off when the store is opened again.

Damage is detected, not trusted. Each Parquet part gets a hidden sidecar ``.part-<...>.parquet.sum`` (rows,
bytes, SHA-256), written atomically before the part is renamed into place; the CSV file gets a hidden
manifest ``DIR/.results.csv.sums`` with one line (offset, bytes, rows, SHA-256) per appended block, written
after the block is on disk. When the store is opened to resume, a part or block that is truncated, emptied,
garbled or unrecorded is named in :attr:`ResultStore.damaged` (one line each) and moved aside (Parquet:
renamed ``.damaged-<name>``; CSV: the file is rewritten from its intact blocks), so its rows are computed
again; nothing damaged counts as done. Reading a damaged store without resuming (:func:`load_results`) is an
error naming the damaged file. Stores written before these records existed are checked by reading them.

Every row carries ``point_id``, a hash of the design point's complete parameter set (the base with the
changes applied, canonicalised), the cycle (name and samples), method, driver (with its tuning), mode, gear
rule and the acceleration settings (:func:`point_identity`). It does not depend on the process, the run, the
order or the Python hash seed, so a resumed sweep recomputes exactly the rows that are absent.
:meth:`ResultStore.read` drops duplicate ``point_id`` rows (keeping the first computed), which can only arise
if two runs were pointed at copies of the same folder and merged.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..textio import read_json
from .spec import SpecError

PARQUET_NAME = "results.parquet"
CSV_NAME = "results.csv"
META_NAME = "sweep.json"
LOCK_NAME = ".sweep.lock"
CSV_SUMS_NAME = ".results.csv.sums"  # the CSV file's block manifest (JSON lines)
SUM_SUFFIX = ".sum"  # a Parquet part's sidecar: .<part name>.sum
FORMATS = ("parquet", "csv")
_ID_LEN = 16


# --- identities ---------------------------------------------------------------------------------------------


def _json_default(value):
    """numpy scalars and arrays as the plain Python values they hold (json knows the rest)."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot canonicalise {type(value).__name__}")


def _digest(obj) -> str:
    """Hash of the canonical JSON form: sorted keys, no spaces, floats as their shortest round-trip repr
    (``repr(0.1) == "0.1"`` on every platform), tuples as lists, ints distinct from floats."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_json_default)
    return hashlib.sha256(text.encode()).hexdigest()[:_ID_LEN]


class DesignValues(dict):
    """A base's flat values without the driver tunings (what a design's identity covers), with each entry's
    canonical JSON text computed once, so identifying the designs of a large sweep costs little."""

    @classmethod
    def of(cls, base_flat: dict) -> DesignValues:
        if isinstance(base_flat, cls):
            return base_flat
        out = cls((k, v) for k, v in base_flat.items() if not k.startswith("drivers."))
        out.fragments = {k: _entry(k, v) for k, v in out.items()}
        return out


_KEYS: dict[str, str] = {}


def _entry(key: str, value) -> str:
    """``"key":value`` exactly as json.dumps writes it (floats by float.__repr__), cheaply for numbers."""
    k = _KEYS.get(key)
    if k is None:
        k = _KEYS.setdefault(key, json.dumps(key))
    if type(value) is float and math.isfinite(value):
        return f"{k}:{float.__repr__(value)}"
    if type(value) is int:
        return f"{k}:{int.__repr__(value)}"
    return f"{k}:" + json.dumps(value, separators=(",", ":"), default=_json_default)


def design_values(base_flat: dict, changes: dict) -> dict:
    """The complete parameter values of a design: the base's flat values with the changes applied.

    ``base_flat`` is :meth:`Parameters.flat` of the base (or a :class:`DesignValues` of it, which saves
    filtering it again for every design of a large sweep)."""
    out = dict(DesignValues.of(base_flat))
    for name, value in _resolved(out, changes):
        out[name] = value
    return out


def _resolved(values: dict, changes: dict):
    """(field, value) pairs of the changes, one gear of a ratio set folded into the whole set."""
    ratios = None
    for name, value in changes.items():
        if name.startswith("transmission.gearbox_ratios["):
            g = int(name[name.index("[") + 1 : -1])
            if ratios is None:
                ratios = list(
                    changes.get("transmission.gearbox_ratios", values["transmission.gearbox_ratios"])
                )
            ratios[g - 1] = value
        elif name == "transmission.gearbox_ratios" and ratios is not None:
            continue
        else:
            yield name, value
    if ratios is not None:
        yield "transmission.gearbox_ratios", tuple(ratios)


def design_identity(base_flat: dict, changes: dict) -> str:
    """Hash of a design's complete parameter set (independent of the cycle and method).

    The hash of the canonical JSON of :func:`design_values` (sorted keys); with a :class:`DesignValues`
    base it is assembled from the precomputed entries, which gives the same text."""
    base = DesignValues.of(base_flat)
    frags = dict(base.fragments)
    for name, value in _resolved(base, changes):
        frags[name] = _entry(name, value)
    text = "{" + ",".join(frags[k] for k in sorted(frags)) + "}"
    return hashlib.sha256(text.encode()).hexdigest()[:_ID_LEN]


def cycle_key(cycle) -> str:
    """A cycle's identity: its name and a hash of its samples."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(cycle.time_s, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(cycle.speed_mps, dtype="<f8").tobytes())
    return f"{cycle.name}:{h.hexdigest()[:_ID_LEN]}"


def point_identity(
    design_id: str,
    cycle: str,
    method: str,
    driver: str,
    driver_values: dict | None,
    mode: str,
    gears: str,
    acceleration: dict | None,
) -> str:
    """Hash of one row: design x cycle x method x driver (with its tuning) x mode x gear rule
    (x acceleration settings)."""
    return _digest(
        {
            "design": design_id,
            "cycle": cycle,
            "method": method,
            "driver": driver,
            "driver_values": driver_values or {},
            "mode": mode,
            "gears": gears,
            "acceleration": acceleration or {},
        }
    )


# --- stores -------------------------------------------------------------------------------------------------


class MemoryStore:
    """Results kept in memory (``run_sweep(..., out=None)``): same interface, nothing on disk."""

    def __init__(self):
        self._frames: list[pd.DataFrame] = []
        self.path = None

    def open(self, *, resume: bool, meta: dict) -> None:  # the same interface as ResultStore
        pass

    def completed(self) -> set[str]:
        return set().union(*(set(f["point_id"]) for f in self._frames)) if self._frames else set()

    def append(self, df: pd.DataFrame) -> None:
        self._frames.append(df)

    def read(self, dedupe: bool = True) -> pd.DataFrame:
        return _finish(pd.concat(self._frames, ignore_index=True) if self._frames else None, dedupe)

    def close(self) -> None:
        pass


class ResultStore:
    """The output folder of a sweep (module docstring). ``fmt`` is ``"parquet"`` or ``"csv"``."""

    def __init__(self, out_dir: str | Path, fmt: str | None = None, schema: dict[str, str] | None = None):
        self.dir = Path(out_dir)
        self.fmt = fmt
        self.schema = schema or {}
        self._lock_fh = None
        self._seq = 0
        self.run_id = ""
        self.damaged: list[str] = []  # damaged parts/blocks found (and moved aside) when opened to resume

    @property
    def path(self) -> Path:
        return self.dir / (PARQUET_NAME if self.fmt == "parquet" else CSV_NAME)

    def exists(self) -> bool:
        return (
            (self.dir / META_NAME).exists()
            or (self.dir / PARQUET_NAME).exists()
            or (self.dir / CSV_NAME).exists()
        )

    def open(self, *, resume: bool, meta: dict) -> None:
        """Create or reopen the folder; take the writer's lock; on resume check it is the same sweep."""
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
        except FileExistsError:
            raise SpecError(f"{self.dir}: a file is in the way, expected the output folder") from None
        except OSError as exc:
            raise SpecError(f"{self.dir}: cannot create the output folder ({exc.strerror or exc})") from None
        self._lock()
        try:
            self._open_locked(resume, meta)
        except BaseException:
            self.close()
            raise

    def _open_locked(self, resume: bool, meta: dict) -> None:
        meta_path = self.dir / META_NAME
        if self.exists():
            if not resume:
                self.close()
                raise SpecError(
                    f"{self.dir} already holds sweep results; pass --resume to complete them "
                    "or choose another --out"
                )
            old = _read_meta(meta_path) if meta_path.exists() else {}
            old_fmt = old.get("format") or ("parquet" if (self.dir / PARQUET_NAME).exists() else "csv")
            if self.fmt is not None and self.fmt != old_fmt:
                self.close()
                raise SpecError(f"{self.dir} holds {old_fmt} results; resume it with format {old_fmt!r}")
            self.fmt = old_fmt
            if old.get("schema") and old["schema"] != self.schema:
                self.close()
                raise SpecError(
                    f"{self.dir}: the spec's parameters differ from the sweep stored there "
                    f"(columns {list(old['schema'])} vs {list(self.schema)}); use another --out"
                )
        else:
            self.fmt = self.fmt or "parquet"
            if self.fmt not in FORMATS:
                self.close()
                raise SpecError(f"format {self.fmt!r} is not one of {', '.join(FORMATS)}")
            _atomic_write(
                meta_path, json.dumps(meta | {"format": self.fmt, "schema": self.schema}, indent=2).encode()
            )
        self.damaged = []
        if self.fmt == "parquet":
            if self.path.exists() and not self.path.is_dir():
                self.close()
                raise SpecError(f"{self.path}: expected the Parquet dataset folder, found a file")
            self.path.mkdir(exist_ok=True)
            for tmp in self.path.glob(".part-*.tmp"):
                tmp.unlink()
            _, damaged = _verify_parts(self.path)
            for part, why in damaged:
                self.damaged.append(f"{part.name}: {why}")
                os.replace(part, part.with_name(f".damaged-{part.name}"))
                _sidecar(part).unlink(missing_ok=True)
            for orphan in self.path.glob(f".part-*{SUM_SUFFIX}"):
                if not (self.path / orphan.name[1 : -len(SUM_SUFFIX)]).exists():
                    orphan.unlink()
        else:
            if self.path.exists() and not self.path.is_file():
                self.close()
                raise SpecError(f"{self.path}: expected the results CSV file, found a folder")
            self._repair_csv()

    def _lock(self) -> None:
        fh = open(self.dir / LOCK_NAME, "a+")  # held (locked) for the life of the store
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.close()
            raise SpecError(
                f"{self.dir} is being written by another sweep; wait for it or stop it first"
            ) from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        self._lock_fh = fh

    def close(self) -> None:
        if self._lock_fh is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self._lock_fh, fcntl.LOCK_UN)
            self._lock_fh.close()
            self._lock_fh = None

    def completed(self) -> set[str]:
        """point_id of every row on disk."""
        if self.fmt == "parquet":  # only the intact parts, and only their point_id column
            import pyarrow.parquet as pq

            good, damaged = _verify_parts(self.path)
            if damaged:
                part, why = damaged[0]
                raise SpecError(f"{part}: damaged sweep result part ({why}); resume the sweep to recompute")
            ids: set[str] = set()
            for part in good:
                ids.update(pq.read_table(part, columns=["point_id"]).column(0).to_pylist())
            return ids
        df = _read_dir(self.dir, self.fmt, self.schema)
        return set() if df is None or "point_id" not in df else set(df["point_id"].dropna().astype(str))

    def _parts(self) -> list[Path]:
        return sorted(p for p in self.path.glob("part-*.parquet"))

    def append(self, df: pd.DataFrame) -> None:
        """Add a finished chunk's rows durably (atomic part file, or one appended CSV block)."""
        if df.empty:
            return
        if list(df.columns) != list(self.schema):  # compute_chunk's frames conform already
            df = conform(df, self.schema)
        if self.fmt == "parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq

            self._seq += 1
            name = f"part-{self.run_id or 'run'}-{self._seq:06d}.parquet"
            tmp = self.path / f".{name}.tmp"
            table = pa.Table.from_pandas(df, schema=arrow_schema(self.schema), preserve_index=False)
            pq.write_table(table, tmp)
            _fsync_path(tmp)
            data = tmp.read_bytes()
            record = {"rows": len(df), "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
            _atomic_write(_sidecar(self.path / name), json.dumps(record).encode())
            os.replace(tmp, self.path / name)
            _fsync_path(self.path)
        else:
            sums = self.dir / CSV_SUMS_NAME
            if not self.path.exists():
                header = df.iloc[:0].to_csv(index=False).encode()
                _atomic_write(self.path, header)
                _atomic_write(sums, (json.dumps(_block(0, header, 0)) + "\n").encode())
            data = df.to_csv(header=False, index=False).encode()
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
            try:
                offset = os.fstat(fd).st_size
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                os.fsync(fd)
            finally:
                os.close(fd)
            _append_line(sums, json.dumps(_block(offset, data, len(df))))

    def _repair_csv(self) -> None:
        """Keep only the intact, recorded blocks of the CSV file (module docstring); damaged ones are named
        in :attr:`damaged`. A store without a manifest (older vpsim): cut a last line left without its
        newline by a killed writer, and set the whole file aside if it does not parse."""
        sums = self.dir / CSV_SUMS_NAME
        if not self.path.exists():
            sums.unlink(missing_ok=True)
            return
        if sums.exists():
            good, damaged, _ = _verify_csv(self.path, sums)
            self.damaged.extend(damaged)
            size = self.path.stat().st_size
            recorded = sum(b["bytes"] for _, b in good)
            if damaged or recorded != size:
                data = self.path.read_bytes()
                if not good or good[0][1]["offset"] != 0 or good[0][1]["rows"] != 0:
                    if data and not damaged:
                        self.damaged.append(f"{self.path.name}: the header is not recorded")
                    self.path.unlink()
                    sums.unlink()
                    return
                body, lines, offset = [], [], 0
                for chunk, b in good:
                    body.append(chunk)
                    lines.append(json.dumps(_block(offset, chunk, b["rows"])))
                    offset += len(chunk)
                _atomic_write(self.path, b"".join(body))
                _atomic_write(sums, ("\n".join(lines) + "\n").encode())
            return
        self._repair_csv_tail()
        data = self.path.read_bytes() if self.path.exists() else b""
        try:
            df = _read_csv_bytes(data, self.schema)
        except Exception as exc:  # noqa: BLE001 - any parse failure means the file cannot be trusted
            self.damaged.append(f"{self.path.name}: {_reason(exc)}")
            os.replace(self.path, self.dir / f".damaged-{self.path.name}")
            return
        # it reads: record it as it is (header, then its rows as one block), so blocks appended now follow
        cut = data.find(b"\n") + 1
        records = [_block(0, data[:cut], 0)] + ([_block(cut, data[cut:], len(df))] if data[cut:] else [])
        _atomic_write(sums, "".join(json.dumps(r) + "\n" for r in records).encode())

    def _repair_csv_tail(self) -> None:
        if not self.path.exists():
            return
        with open(self.path, "rb+") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            if size == 0:
                return
            fh.seek(size - 1)
            if fh.read(1) == b"\n":
                return
            block = 1 << 16
            pos = size
            while pos > 0:
                start = max(0, pos - block)
                fh.seek(start)
                buf = fh.read(pos - start)
                k = buf.rfind(b"\n")
                if k >= 0:
                    fh.truncate(start + k + 1)
                    fh.flush()
                    os.fsync(fh.fileno())
                    return
                pos = start
            fh.truncate(0)

    def read(self, dedupe: bool = True) -> pd.DataFrame:
        """All rows as a DataFrame (duplicates of a point_id dropped unless ``dedupe=False``)."""
        return _finish(_read_dir(self.dir, self.fmt, self.schema), dedupe, self.schema)


def load_results(path: str | Path, *, dedupe: bool = True) -> pd.DataFrame:
    """The results of a sweep: its output folder, or its ``results.parquet`` / ``results.csv``."""
    path = Path(path)
    if path.name in (PARQUET_NAME, CSV_NAME):
        path = path.parent
    fmt = "parquet" if (path / PARQUET_NAME).exists() else "csv" if (path / CSV_NAME).exists() else None
    if fmt is None:
        raise SpecError(f"{path}: no {PARQUET_NAME} or {CSV_NAME} here")
    schema = _read_meta(path / META_NAME).get("schema", {}) if (path / META_NAME).exists() else {}
    return _finish(_read_dir(path, fmt, schema), dedupe, schema)


def _read_dir(path: Path, fmt: str, schema: dict) -> pd.DataFrame | None:
    """The rows of the store in ``path``; a damaged part or block is an error naming it."""
    if fmt == "parquet":
        import pyarrow.parquet as pq

        good, damaged = _verify_parts(path / PARQUET_NAME)
        if damaged:
            part, why = damaged[0]
            raise SpecError(
                f"{part}: damaged sweep result part ({why}); run the sweep again with --resume to recompute "
                f"its rows ({len(damaged)} damaged part(s))"
            )
        if not good:
            return None
        return pd.concat([pq.read_table(p).to_pandas() for p in good], ignore_index=True)
    f = path / CSV_NAME
    if not f.exists():
        return None
    sums = path / CSV_SUMS_NAME
    if sums.exists():
        good, damaged, _ = _verify_csv(f, sums)
        if damaged:
            raise SpecError(
                f"{f}: damaged sweep results ({damaged[0]}); run the sweep again with --resume to recompute "
                "those rows"
            )
        data = b"".join(chunk for chunk, _ in good)  # an unrecorded tail (a killed write) is not read
    else:
        data = f.read_bytes()
        if data and not data.endswith(b"\n"):
            data = data[: data.rfind(b"\n") + 1]  # a last line cut by a kill
    if not data:
        return None
    try:
        return _read_csv_bytes(data, schema)
    except Exception as exc:  # noqa: BLE001 - a file that does not parse is damaged
        raise SpecError(
            f"{f}: damaged sweep results ({_reason(exc)}); run the sweep again with --resume to recompute"
        ) from None


def _read_csv_bytes(data: bytes, schema: dict) -> pd.DataFrame:
    import io

    dtype = {c: str for c, t in schema.items() if t == "str"} or {"point_id": str}
    df = pd.read_csv(
        io.BytesIO(data),
        dtype=dtype,
        keep_default_na=False,
        na_values={c: [""] for c in dtype}
        | {c: ["", "nan", "NaN"] for c, t in schema.items() if t == "float"},
        on_bad_lines="error",
    )
    if schema and list(df.columns) != list(schema):
        raise ValueError(f"columns {list(df.columns)[:6]} are not the sweep's {list(schema)[:6]}")
    for col, typ in schema.items():
        if typ in ("int", "bool") and df[col].isna().any():
            raise ValueError(f"column {col!r} has an empty value in a row")
    if "point_id" in df and (df["point_id"].isna() | (df["point_id"].astype(str).str.len() == 0)).any():
        raise ValueError("a row has no point_id")
    return conform(df, schema)


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:200]


def _sidecar(part: Path) -> Path:
    return part.with_name(f".{part.name}{SUM_SUFFIX}")


def _verify_parts(folder: Path) -> tuple[list[Path], list[tuple[Path, str]]]:
    """(intact parts, [(damaged part, why)]) of a Parquet dataset folder."""
    import pyarrow.parquet as pq

    if not folder.is_dir():
        return [], []
    good: list[Path] = []
    damaged: list[tuple[Path, str]] = []
    for part in sorted(folder.glob("part-*.parquet")):
        if not part.is_file():  # a FIFO would block the read, a device never end
            damaged.append((part, "not a regular file"))
            continue
        try:
            data = part.read_bytes()
        except OSError as exc:
            damaged.append((part, f"cannot read ({exc.strerror or exc})"))
            continue
        side = _sidecar(part)
        if side.exists():
            try:
                rec = read_json(side, SpecError, what="checksum record")
                ok = isinstance(rec, dict) and all(k in rec for k in ("rows", "bytes", "sha256"))
            except SpecError:  # unreadable, not JSON, nested too deeply, a FIFO
                ok = False
            if not ok:
                damaged.append((part, "its checksum record is unreadable"))
            elif len(data) != rec["bytes"]:
                damaged.append((part, f"{len(data)} bytes, {rec['bytes']} were written (truncated?)"))
            elif hashlib.sha256(data).hexdigest() != rec["sha256"]:
                damaged.append((part, "checksum mismatch (garbled)"))
            else:
                good.append(part)
            continue
        try:  # a part of an older vpsim, without a record: it must read completely
            pq.read_table(part)
        except Exception as exc:  # noqa: BLE001 - any failure to read means damaged
            damaged.append((part, f"unreadable ({_reason(exc)})"))
            continue
        good.append(part)
    return good, damaged


def _block(offset: int, data: bytes, rows: int) -> dict:
    return {"offset": offset, "bytes": len(data), "rows": rows, "sha256": hashlib.sha256(data).hexdigest()}


def _verify_csv(path: Path, sums: Path) -> tuple[list[tuple[bytes, dict]], list[str], int]:
    """([(block bytes, record)] intact, [damaged block, why], end of the recorded data) of a CSV store.
    The blocks must follow each other from the header; once one is damaged, those after it are kept only if
    they are intact themselves."""
    data = path.read_bytes()
    good: list[tuple[bytes, dict]] = []
    damaged: list[str] = []
    end = 0
    try:
        lines = sums.read_text().splitlines()
    except (OSError, ValueError) as exc:
        return [], [f"{sums.name}: unreadable ({_reason(exc)})"], 0
    for k, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            b = json.loads(line)
            ok = isinstance(b, dict) and all(isinstance(b.get(x), int) for x in ("offset", "bytes", "rows"))
            ok = ok and isinstance(b.get("sha256"), str)
        except ValueError:
            ok = False
        if not ok:
            if k == len(lines) - 1:  # a manifest line cut by a kill: its block is unrecorded
                break
            damaged.append(f"{sums.name} line {k + 1}: unreadable record")
            continue
        lo, hi = b["offset"], b["offset"] + b["bytes"]
        chunk = data[lo:hi]
        what = "the header" if k == 0 else f"rows at bytes {lo}-{hi} ({b['rows']} rows)"
        if len(chunk) != b["bytes"]:
            damaged.append(f"{path.name}: {what} cut short (file has {len(data)} bytes)")
        elif hashlib.sha256(chunk).hexdigest() != b["sha256"]:
            damaged.append(f"{path.name}: {what} garbled (checksum mismatch)")
        elif k == 0 and lo != 0:
            damaged.append(f"{path.name}: the header record does not start the file")
        else:
            good.append((chunk, b))
            end = max(end, hi)
    return good, damaged, end


def _append_line(path: Path, line: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        data = (line + "\n").encode()
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    finally:
        os.close(fd)


def _finish(df: pd.DataFrame | None, dedupe: bool, schema: dict | None = None) -> pd.DataFrame:
    if df is None:
        return pd.DataFrame(columns=list(schema or []))
    for col in ("driver", "accel_note", "warning"):
        if col in df:
            df[col] = df[col].fillna("").astype(str)
    if dedupe and "point_id" in df:
        if "computed_at" in df:
            df = df.sort_values("computed_at", kind="stable")
        df = df.drop_duplicates("point_id", keep="first")
    sort = [c for c in ("design", "cycle", "method", "driver") if c in df]
    return df.sort_values(sort, kind="stable").reset_index(drop=True) if sort else df.reset_index(drop=True)


# --- column types -------------------------------------------------------------------------------------------


def conform(df: pd.DataFrame, schema: dict[str, str]) -> pd.DataFrame:
    """Columns in schema order with schema types ("str", "float", "int", "bool")."""
    if not schema:
        return df
    out = {}
    for col, typ in schema.items():
        s = df[col] if col in df else pd.Series([None] * len(df), index=df.index)
        if typ == "float":
            out[col] = pd.to_numeric(s, errors="coerce").astype("float64")
        elif typ == "int":
            out[col] = s.astype("int64")
        elif typ == "bool":
            out[col] = s.astype(bool)
        else:
            out[col] = s.astype(object).where(s.notna(), None)
    return pd.DataFrame(out)


def arrow_schema(schema: dict[str, str]):
    import pyarrow as pa

    types = {"str": pa.string(), "float": pa.float64(), "int": pa.int64(), "bool": pa.bool_()}
    return pa.schema([(c, types[t]) for c, t in schema.items()])


def _read_meta(path: Path) -> dict:
    try:
        meta = read_json(path, SpecError, what="sweep record")
    except SpecError as exc:  # (a FIFO or device is refused before it is opened)
        raise SpecError(
            f"{path}: cannot read the sweep's record ({str(exc).removeprefix(f'{path}: ')})"
        ) from None
    if not isinstance(meta, dict) or not isinstance(meta.get("schema", {}), dict):
        raise SpecError(f"{path}: the sweep's record is not a JSON object with a schema; use another --out")
    if meta.get("format") not in (None, *FORMATS):
        raise SpecError(f"{path}: the sweep's record names format {meta.get('format')!r}; use another --out")
    return meta


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    _fsync_path(path.parent)
