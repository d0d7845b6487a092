"""Writing a file so that a reader never sees half of it."""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def write_atomic(path: str | os.PathLike, data: str | bytes, private: bool = False) -> Path:
    """Write ``data`` to a temporary file beside ``path``, then rename it over ``path``: a
    reader (another process, a run resumed after a kill) sees the old file or the new one,
    never a part. The temporary name is the writer's own (its pid and a random part: several
    processes, each pid 1 in its container, may write into one folder). ``private``: created
    mode 0600, never readable by others, not even briefly (a key); otherwise as ``open`` would
    (0666 less the umask). Returns ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if private else 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
