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

from .spec import SpecError

PARQUET_NAME = "results.parquet"
CSV_NAME = "results.csv"
META_NAME = "sweep.json"
LOCK_NAME = ".sweep.lock"
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
        self.dir.mkdir(parents=True, exist_ok=True)
        self._lock()
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
        if self.fmt == "parquet":
            self.path.mkdir(exist_ok=True)
            for tmp in self.path.glob(".part-*.tmp"):
                tmp.unlink()
        else:
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
        if self.fmt == "parquet":
            import pyarrow.parquet as pq

            ids: set[str] = set()
            for part in self._parts():
                ids.update(pq.read_table(part, columns=["point_id"]).column(0).to_pylist())
            return ids
        if not self.path.exists():
            return set()
        return set(pd.read_csv(self.path, usecols=["point_id"], dtype=str)["point_id"])

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
            os.replace(tmp, self.path / name)
            _fsync_path(self.path)
        else:
            if not self.path.exists():
                _atomic_write(self.path, df.iloc[:0].to_csv(index=False).encode())
            data = df.to_csv(header=False, index=False).encode()
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                os.fsync(fd)
            finally:
                os.close(fd)

    def _repair_csv(self) -> None:
        """Cut a last line left without its newline by a killed writer."""
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
    if fmt == "parquet":
        import pyarrow.parquet as pq

        parts = sorted((path / PARQUET_NAME).glob("part-*.parquet"))
        if not parts:
            return None
        return pd.concat([pq.read_table(p).to_pandas() for p in parts], ignore_index=True)
    f = path / CSV_NAME
    if not f.exists():
        return None
    dtype = {c: str for c, t in schema.items() if t == "str"} or {"point_id": str}
    return conform(
        pd.read_csv(
            f,
            dtype=dtype,
            keep_default_na=False,
            na_values={c: [""] for c in dtype}
            | {c: ["", "nan", "NaN"] for c, t in schema.items() if t == "float"},
        ),
        schema,
    )


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
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise SpecError(f"{path}: cannot read the sweep's record ({exc})") from None


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
