"""Atomic output helpers: write to a temporary file beside the target, then rename."""
from __future__ import annotations

import contextlib
import errno
import json
import os
import pickle
import tempfile
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["atomic_path", "atomic_open", "save_npy", "save_json", "save_figure", "save_image", "locked",
           "check_writable", "is_versioned_npz", "load_npy", "claimed"]


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; rename it to ``path`` on success.

    ``suffix`` defaults to the target's suffix so that libraries which pick a format from the file name (matplotlib,
    OpenCV, NumPy) still work.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix if suffix is not None else path.suffix,
                                   dir=path.parent)
    except OSError as exc:
        raise _write_error(exc, path) from exc
    os.close(fd)
    try:
        # mkstemp creates 0600; results should get the permissions of an ordinary new file
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, _TargetWriteError):
            # the temporary name means nothing to the user: name the file being written
            raise _write_error(exc, path) from exc
        raise


def check_writable(path, what: str = "output") -> Path:
    """Refuse, before any work, a file that cannot be written: a folder there, or no write access to its folder.

    Raises ValueError (a folder in the way) or OSError (EACCES / EROFS) naming ``path`` and ``what`` it is for;
    returns ``path``.
    """
    path = Path(path)
    if path.is_dir() or str(path).endswith(("/", os.sep)):
        raise ValueError(f"{what} {path}: is a folder, expected a file name (e.g. {path / 'out.npz'})")
    anc = path.parent.absolute()
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if not anc.is_dir():
        raise ValueError(f"{what} {path}: {anc} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        readonly = hasattr(os, "statvfs") and os.statvfs(anc).f_flag & getattr(os, "ST_RDONLY", 1)
        code = errno.EROFS if readonly else errno.EACCES
        raise OSError(code, f"{what}: cannot write ({os.strerror(code)})", str(path))
    return path


class _TargetWriteError(OSError):
    """An OSError while writing a result, naming the result (not its temporary file)."""


def _write_error(exc: OSError, path: Path) -> OSError:
    return _TargetWriteError(exc.errno, f"cannot write ({exc.strerror or exc})", str(path))


@contextlib.contextmanager
def _flocked(path, wait: bool):
    """Hold ``fcntl.flock`` on ``path`` (created if missing); yields False where the lock is held elsewhere and
    ``wait`` is off. Advisory, released if the process dies; where ``fcntl`` does not exist (Windows), unlocked.

    The lock file is removed when the lock is released (a run leaves no ``.lock`` behind), and so is its folder when
    this lock made it and it is left empty: unlinked while held, so that a process that opened the old file meanwhile
    sees it gone and locks a new one.
    """
    try:
        import fcntl  # POSIX only
    except ImportError:  # pragma: no cover - Windows
        fcntl = None
    path = Path(path)
    made = not path.parent.exists()
    while True:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fh = open(path, "a")
        except OSError as exc:
            raise _write_error(exc, path) from exc
        if fcntl is None:
            with fh:
                yield True
            return
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            fh.close()
            yield False
            return
        try:
            same = os.fstat(fh.fileno()).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        fh.close()  # the holder before removed it on release: lock the file there now
    with fh:
        try:
            yield True
        finally:
            with contextlib.suppress(OSError):
                path.unlink()
                if made:
                    path.parent.rmdir()  # only if empty
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


@contextlib.contextmanager
def locked(path):
    """Hold an exclusive lock on the file ``path`` (created if missing) for a read-modify-write (waits for it)."""
    with _flocked(path, wait=True):
        yield


@contextlib.contextmanager
def claimed(path, what: str):
    """Hold an exclusive lock on ``path`` (created if missing) for a whole run, or refuse at once.

    A second run that would write the same results while the first still runs gets a ValueError naming ``what``,
    instead of silently replacing the first run's files. The lock goes with the process.
    """
    with _flocked(path, wait=False) as got:
        if not got:
            raise ValueError(f"{what}: another run is writing it now; wait for it, or choose another --out")
        yield


@contextlib.contextmanager
def atomic_open(path, mode: str = "w", **kwargs):
    """Like :func:`open` for writing, but atomic."""
    with atomic_path(path) as tmp:
        with open(tmp, mode, **kwargs) as fh:
            yield fh


def save_npy(path, array) -> Path:
    """Atomically save one array as ``.npy``."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, np.asarray(array))
    return Path(path)


def save_json(path, obj, indent: int = 2) -> Path:
    """Atomically write ``obj`` as JSON (NumPy scalars and arrays are converted)."""

    def default(o):
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, Path):
            return str(o)
        raise TypeError(f"not JSON serialisable: {type(o).__name__}")

    with atomic_open(path, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=indent, default=default)
        fh.write("\n")
    return Path(path)


#: zlib level of the PNG figures: the fastest (level 6, PIL's default, costs a plot a quarter more for files 10 %
#: smaller)
PNG_COMPRESS_LEVEL = 1


def save_figure(fig, path, **kwargs) -> Path:
    """Atomically save a matplotlib figure (format from the suffix; a PNG compressed at :data:`PNG_COMPRESS_LEVEL`)."""
    if Path(path).suffix.lower() == ".png":
        kwargs.setdefault("pil_kwargs", {"compress_level": PNG_COMPRESS_LEVEL})
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return Path(path)


def save_image(path, img) -> Path:
    """Atomically write an image with OpenCV (format from the suffix)."""
    import cv2  # slow to import; most writers here need only NumPy and json

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"{path}: OpenCV could not encode the image")
    return Path(path)


def save_versioned_npz(path, header: dict, arrays: dict, default=None) -> Path:
    """Atomically write ``arrays`` and a JSON ``header`` (with ``format`` and ``version``) as one ``.npz``."""
    path = Path(path)
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, header=np.array(json.dumps(header, default=default)), **arrays)
    return path


def load_versioned_npz(path, fmt: str, version: int, what: str, error: type[Exception] = ValueError,
                       hint: str = "") -> tuple[dict, dict]:
    """Read a file of :func:`save_versioned_npz`: ``(header, arrays)``.

    Raises ``error`` naming ``path`` when the file is missing, unreadable, of another format (``what`` names the
    expected one, ``hint`` says what writes it) or of another version.
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: no such {what} file")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        header = json.loads(str(data.pop("header")))
    except Exception as e:  # zip, format and JSON errors all mean "not our file"
        # numpy's own words would suggest loading it "unsafely" with allow_pickle: not what to do here
        reason = "not an .npz archive" if not zipfile.is_zipfile(path) else f"unreadable content ({type(e).__name__})"
        raise error(f"{path}: not a readable {what} file{hint}: {reason}") from e
    if not isinstance(header, dict) or header.get("format") != fmt:
        raise error(f"{path}: not a {what} file{hint}")
    if header.get("version") != version:
        raise error(f"{path}: unsupported {what} format version {header.get('version')}")
    return header, data


def versioned_npz_header(path) -> dict | None:
    """The JSON header of a file of :func:`save_versioned_npz` (None: not such a file), read without its arrays."""
    path = Path(path)
    if not path.is_file() or not zipfile.is_zipfile(path):
        return None
    try:
        with zipfile.ZipFile(path) as z:
            if "header.npy" not in z.namelist():
                return None
            with z.open("header.npy") as fh:
                header = json.loads(str(np.lib.format.read_array(fh, allow_pickle=False)))
    except (OSError, ValueError, zipfile.BadZipFile):
        return None
    return header if isinstance(header, dict) else None


def is_versioned_npz(path, fmt: str | None = None) -> bool:
    """Whether ``path`` is a file of :func:`save_versioned_npz` (of format ``fmt``), whatever its name."""
    header = versioned_npz_header(path)
    return header is not None and (fmt is None or header.get("format") == fmt)


#: The only globals a ``.npy`` of Python objects may name: how NumPy pickles its arrays, dtypes and
#: scalars (``numpy.core`` before NumPy 2, ``numpy._core`` since). Lists, tuples, numbers and strings
#: need no global. Nothing here runs code of the file's choosing.
_NUMPY_PICKLE_GLOBALS = frozenset({
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
})


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles NumPy arrays, dtypes, scalars and plain containers; refuses every other global."""

    def find_class(self, module, name):
        if (module, name) in _NUMPY_PICKLE_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"it names {module}.{name}, which is not a NumPy array, list or number")

    def persistent_load(self, pid):
        raise pickle.UnpicklingError("it refers to an external object")


def load_npy(path, what: str = "file") -> np.ndarray:
    """Read a ``.npy`` file without ever executing code from it.

    Numeric arrays are read as :func:`numpy.load` with ``allow_pickle=False`` does. An array of Python objects
    (VPR-Bench's ``ground_truth_new.npy`` holds lists per query) is unpickled by an unpickler that admits only NumPy
    arrays, dtypes and scalars besides lists, tuples, numbers and strings: ``numpy.load`` with pickles allowed would
    run whatever a crafted file names. A file without the NumPy header (e.g. a bare pickle or text under a ``.npy``
    name) is refused. Every refusal is a ``ValueError`` naming ``path`` (``what`` says what the file is for).
    """
    path = Path(path)
    fmt = np.lib.format
    try:
        with open(path, "rb") as fh:
            if fh.read(len(fmt.MAGIC_PREFIX)) != fmt.MAGIC_PREFIX:
                raise ValueError("no NumPy .npy header")
            fh.seek(0)
            version = fmt.read_magic(fh)
            if version == (1, 0):
                shape, fortran, dtype = fmt.read_array_header_1_0(fh)
            elif version == (2, 0):
                shape, fortran, dtype = fmt.read_array_header_2_0(fh)
            else:
                raise ValueError(f".npy format version {version[0]}.{version[1]} is not read here")
            if not dtype.hasobject:
                fh.seek(0)
                return np.load(fh, allow_pickle=False)
            try:
                arr = _NumpyOnlyUnpickler(fh).load()
            except (pickle.UnpicklingError, EOFError, AttributeError, TypeError, ValueError, IndexError,
                    KeyError, MemoryError, UnicodeDecodeError, OverflowError) as e:
                raise ValueError(f"refused to read its Python objects ({e})") from None
    except OSError as e:
        raise ValueError(f"{path}: not a readable {what} ({e.strerror or e})") from None
    except ValueError as e:
        raise ValueError(f"{path}: not a readable {what}: {e}") from None
    if not isinstance(arr, np.ndarray) or arr.shape != tuple(shape):
        raise ValueError(f"{path}: not a readable {what}: its objects are not the array its header declares")
    return arr
