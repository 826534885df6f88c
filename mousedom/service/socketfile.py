"""The socket file: where it goes, who may reach it, and one daemon per path.

The directory must belong to this user or root (nobody else could swap the socket), the
file gets ``server.group`` and ``server.mode`` before anyone can connect, a socket left by
a crash is removed and one with a live daemon behind it refused (before any sensor is
opened and grabbed).
"""

from __future__ import annotations

import grp
import logging
import os
import socket
import stat

from mousedom.config import ServerConfig
from mousedom.errors import UserError

log = logging.getLogger(__name__)

SOCKET_NAME = "mousedom.sock"
MAX_SOCKET_PATH = 107  # sizeof(sockaddr_un.sun_path) on Linux, less its terminating NUL


def default_socket_path(environ: dict[str, str] | None = None, uid: int | None = None) -> str:
    """Where the socket goes when the config does not say.

    Under systemd, $RUNTIME_DIRECTORY (from RuntimeDirectory=); as root /run/mousedom; as a
    user $XDG_RUNTIME_DIR, else a per-user directory under the temporary directory.
    """
    env = os.environ if environ is None else environ
    uid = os.getuid() if uid is None else uid
    runtime = env.get("RUNTIME_DIRECTORY")
    if runtime:
        return os.path.join(runtime.split(":")[0], SOCKET_NAME)
    if uid == 0:
        return os.path.join("/run/mousedom", SOCKET_NAME)
    xdg = env.get("XDG_RUNTIME_DIR")
    if xdg:
        return os.path.join(xdg, "mousedom", SOCKET_NAME)
    tmp = env.get("TMPDIR") or "/tmp"
    return os.path.join(tmp, f"mousedom-{uid}", SOCKET_NAME)


def check_path(path: str) -> None:
    """UserError if ``path`` is too long for a Unix socket's address."""
    size = len(os.fsencode(path))
    if size > MAX_SOCKET_PATH:
        raise UserError(
            f"{path}: the socket path is {size} bytes, longer than the "
            f"{MAX_SOCKET_PATH} a Unix socket's address holds; give a shorter --socket "
            "or server.socket"
        )


def listen(path: str, settings: ServerConfig) -> socket.socket:
    """The listening socket at ``path``, made with the owner, group and mode the settings
    say (nobody gets in before they apply); a stale socket left by a crash is removed."""
    check_path(path)
    directory = os.path.dirname(path) or "."
    try:
        os.makedirs(directory, mode=0o755, exist_ok=True)
        owner = os.stat(directory).st_uid
    except OSError as e:
        raise UserError(f"{path}: cannot create the socket directory: {e.strerror}") from None
    if owner not in (os.getuid(), 0):
        # e.g. /tmp/mousedom-UID made by someone else, who could swap the socket
        raise UserError(
            f"{directory}: belongs to uid {owner}, not to this user or root; "
            "not putting the socket there (give --socket)"
        )
    gid = None
    if settings.group:
        try:
            gid = grp.getgrnam(settings.group).gr_gid
        except KeyError:
            raise UserError(f"{path}: server.group: no group named {settings.group!r}") from None
    remove_stale(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
    old_umask = os.umask(0o177)  # nobody gets in before chmod below says who may
    try:
        sock.bind(path)
    except OSError as e:
        sock.close()
        raise UserError(f"{path}: cannot bind the socket: {e.strerror or e}") from None
    finally:
        os.umask(old_umask)
    try:
        if gid is not None:
            os.chown(path, -1, gid)
        os.chmod(path, settings.mode)
    except OSError as e:
        sock.close()
        os.unlink(path)
        raise UserError(f"{path}: cannot set owner or mode: {e.strerror}") from None
    sock.listen(16)
    sock.setblocking(False)
    return sock


def refuse_if_taken(path: str) -> None:
    """UserError if another daemon listens at the path already: checked before the
    sensors are opened, so that a second daemon grabs no device on its way out."""
    check_path(path)
    try:
        if not stat.S_ISSOCK(os.lstat(path).st_mode):
            return  # open() says what is wrong with it
    except OSError:
        return
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(path)
    except OSError:
        return  # stale: open() removes it
    finally:
        probe.close()
    raise UserError(f"{path}: another mousedom daemon is listening there")


def remove_stale(path: str) -> None:
    """A socket file left by a crash is removed; one with a live daemon behind it is not."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise UserError(f"{path}: exists and is not a socket; not touching it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(path)
    except OSError:
        os.unlink(path)
        log.info("removed stale socket %s", path)
        return
    finally:
        probe.close()
    raise UserError(f"{path}: another mousedom daemon is listening there")
