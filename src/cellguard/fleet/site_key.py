"""The site's secret key: what signature ids are keyed with, so an id tells nothing of withheld fields.

``SITE_DIR/site.key``, 32 random bytes as 64 hex digits, owner-only (0600), made at the site's
first push and never sent anywhere. The same site keeps the same key, so a finding pushed again
keeps its id (re-pushes add nothing); anyone without the key (the operator, other tenants) cannot
test a guess of a withheld field against an id. A folder whose audit log says batches went to the store
without its key (a version before the key, or a key since lost) gets none from a push, which is
refused (``push.check_key_history``: a new key stored every finding again under new ids);
``fleet withdraw`` deletes what the site pooled and makes it, then the site pushes again.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import secrets
import stat
from pathlib import Path

from cellguard.errors import ConfigError, OutputError

KEY_FILE = "site.key"
_KEY = re.compile(r"[0-9a-f]{64}")


def site_key(site_dir: Path) -> bytes:
    """The site's key, made (mode 0600, written beside and linked into place) if it is not there yet;
    ConfigError naming the file when it is not a key only its owner can read."""
    path = Path(site_dir) / KEY_FILE
    make_key(site_dir)
    try:
        st = os.lstat(path)
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(f"site key {path}: not a regular file")
        if st.st_mode & 0o077:
            raise ConfigError(f"site key {path}: readable by others (mode {stat.S_IMODE(st.st_mode):o}); "
                              f"chmod 600 it")
        text = path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"site key {path}: cannot read it ({exc.__class__.__name__})") from None
    if not _KEY.fullmatch(text):
        raise ConfigError(f"site key {path}: expected 64 hex digits; restore the site's key (signature ids "
                          f"depend on it) or remove the file to start a new one")
    return bytes.fromhex(text)


def fingerprint(key: bytes) -> str:
    """16 hex digits naming ``key`` without revealing it: what a queued batch says its ids were keyed with."""
    return hmac.new(key, b"cellguard site key", hashlib.sha256).hexdigest()[:16]


def make_key(site_dir: Path) -> bool:
    """Make the site's key if it is not there; whether this process made it (of two first pushes at once, the one
    whose link won: only it says a new key was made)."""
    path = Path(site_dir) / KEY_FILE
    return False if os.path.lexists(path) else _create(path)


def _create(path: Path) -> bool:
    """A fresh key at ``path``, True; one made meanwhile by another push is kept (linking never overwrites), False.
    The temporary file is removed only once made: removing it from a folder that could not be made raised past the
    error that names the key."""
    tmp = path.with_name(f"{KEY_FILE}.{secrets.token_hex(4)}.tmp")
    made = False
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), "w") as f:
            made = True
            f.write(secrets.token_hex(32) + "\n")
            f.flush()
            os.fsync(f.fileno())
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        return True
    except OSError as exc:
        raise OutputError(f"site key {path}: cannot write ({exc.strerror or exc.__class__.__name__})") from None
    finally:
        if made:
            tmp.unlink(missing_ok=True)
