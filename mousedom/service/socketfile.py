"""The socket file: where it goes, who may reach it, and one daemon per path.

The directory must belong to this user or root (nobody else could swap the socket), the
file gets ``server.group`` and ``server.mode`` before anyone can connect, a socket left by
a crash is removed and one with a live daemon behind it refused (before any sensor is
opened and grabbed).  A reload sets the group and mode again, the same way (``reapply``).
"""

from __future__ import annotations

import grp
import logging
import os
import socket
import stat
from dataclasses import dataclass, replace

from mousedom.config import ServerConfig
from mousedom.config.outputs import MAX_SOCKET_PATH
from mousedom.errors import UserError

log = logging.getLogger(__name__)

SOCKET_NAME = "mousedom.sock"


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


@dataclass(frozen=True)
class Access:
    """The socket file a daemon listens at and who may reach it: the file's identity
    (device, inode), the group it was made with (what it has without ``server.group``),
    and the mode and group set on it."""

    path: str
    identity: tuple[int, int]
    made_gid: int
    mode: int
    gid: int


def _group_id(group: str | None) -> int | None:
    """``server.group``'s id (None: none named); KeyError if there is no such group."""
    return None if not group else grp.getgrnam(group).gr_gid


def listen(path: str, settings: ServerConfig) -> tuple[socket.socket, Access]:
    """The listening socket at ``path``, made with the owner, group and mode the settings
    say (nobody gets in before they apply), and what was set on it; a stale socket left
    by a crash is removed."""
    check_path(path)
    directory = os.path.dirname(path) or "."
    try:
        os.makedirs(directory, mode=0o755, exist_ok=True)
        dir_stat = os.stat(directory)
    except OSError as e:
        raise UserError(f"{path}: cannot create the socket directory: {e.strerror}") from None
    owner = dir_stat.st_uid
    if dir_stat.st_mode & stat.S_IWOTH and not dir_stat.st_mode & stat.S_ISVTX:
        # (as /tmp, a shared folder needs the sticky bit: else anyone may swap the socket)
        raise UserError(
            f"{directory}: anyone may write there (mode {stat.S_IMODE(dir_stat.st_mode):04o}, "
            "no sticky bit) and so replace the socket; not putting it there (give --socket)"
        )
    if owner not in (os.getuid(), 0):
        # e.g. /tmp/mousedom-UID made by someone else, who could swap the socket
        raise UserError(
            f"{directory}: belongs to uid {owner}, not to this user or root; "
            "not putting the socket there (give --socket)"
        )
    try:
        gid = _group_id(settings.group)
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
        made = os.lstat(path)
        if gid is not None:
            os.chown(path, -1, gid)
        os.chmod(path, settings.mode)
    except OSError as e:
        sock.close()
        os.unlink(path)
        raise UserError(f"{path}: cannot set owner or mode: {e.strerror}") from None
    sock.listen(16)
    sock.setblocking(False)
    access = Access(path, (made.st_dev, made.st_ino), made.st_gid, settings.mode,
                    made.st_gid if gid is None else gid)  # fmt: skip
    return sock, access


def reapply(access: Access, settings: ServerConfig) -> Access:
    """A reload's ``server.group`` and ``server.mode`` on the socket in use, as ``listen``
    sets them (no group named: the group it was made with); what is set now.

    Both or neither: a group that does not exist or cannot be given (not root, and not a
    member of it) keeps the mode as it is too, with one logged line, for a new mode on
    the old group could open the socket to the wrong people.  While the group changes, the
    file has only the permissions both the old and the new mode give to owner and others,
    and none to a group, so nobody can connect in between who could not before and after.
    Clients already connected stay (a Unix socket's permissions are checked at connect).
    """
    path = access.path
    try:
        gid = _group_id(settings.group)
    except KeyError:
        log.error(
            "server.group: no group named %r: the socket %s keeps mode %04o and group %d",
            settings.group, path, access.mode, access.gid,
        )  # fmt: skip
        return access
    if gid is None:
        gid = access.made_gid
    try:
        st = os.lstat(path)
    except OSError as e:
        log.warning("%s: %s; its mode and group are not changed", path, e.strerror)
        return access
    if not _made(access, st):
        log.warning("%s: not the socket this daemon made any more; not touching it", path)
        return access
    if gid != st.st_gid:
        try:
            os.chmod(path, access.mode & settings.mode & 0o707)
            os.chown(path, -1, gid)
        except OSError as e:
            log.error(
                "%s: cannot give it to group %s: %s; it keeps mode %04o and group %d",
                path, settings.group or gid, e.strerror, access.mode, st.st_gid,
            )  # fmt: skip
            try:
                os.chmod(path, access.mode)
            except OSError:
                pass
            return replace(access, gid=st.st_gid)
    try:
        os.chmod(path, settings.mode)
    except OSError as e:
        log.warning("cannot set mode of %s: %s", path, e.strerror)
        return replace(access, gid=gid)
    return replace(access, mode=settings.mode, gid=gid)


def _made(access: Access, st: os.stat_result) -> bool:
    """Whether the file ``st`` (an lstat of ``access.path``) is still the socket this
    daemon made there: a socket of the same device and inode (an operator may have
    removed it, and another daemon made its own at the path since)."""
    return stat.S_ISSOCK(st.st_mode) and (st.st_dev, st.st_ino) == access.identity


def refuse_if_taken(path: str) -> None:
    """UserError if another daemon listens at the path already: checked before the
    sensors are opened, so that a second daemon grabs no device on its way out."""
    check_path(path)
    try:
        if not stat.S_ISSOCK(os.lstat(path).st_mode):
            return  # open() says what is wrong with it
    except OSError:
        return
    if _listening(path):
        raise UserError(f"{path}: another mousedom daemon is listening there")


def _listening(path: str) -> bool:
    """Whether a live process listens at the socket ``path``.  Only a refused connection
    says stale: a full listen backlog (a busy or stopped daemon) is a live one, and a
    connection we may not make (the socket's mode) says nothing either way: a UserError,
    where removing the file would cut a running daemon off from its clients.  The probe
    never waits (non-blocking connect)."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.setblocking(False)
    try:
        probe.connect(path)
    except (ConnectionRefusedError, FileNotFoundError):
        return False
    except BlockingIOError:
        return True  # EAGAIN: its backlog is full
    except OSError as e:
        raise UserError(
            f"{path}: cannot tell whether a daemon listens there ({e.strerror}); not "
            "touching it: remove it by hand if no daemon runs"
        ) from e
    finally:
        probe.close()
    return True


def remove_stale(path: str) -> None:
    """A socket file left by a crash is removed; one with a live daemon behind it is not."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise UserError(f"{path}: exists and is not a socket; not touching it")
    if _listening(path):
        raise UserError(f"{path}: another mousedom daemon is listening there")
    try:
        os.unlink(path)
    except FileNotFoundError:
        return
    log.info("removed stale socket %s", path)


def remove_own(access: Access) -> None:
    """The daemon's socket file removed at its exit, where it is still the one it made
    (``access.identity``): an operator who removed it while the daemon ran and started
    another daemon at the same path gave the path to that one, and the first one's exit
    took it from under it (the second ran on with no socket to reach it by)."""
    path = access.path
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not _made(access, st):
        log.warning("%s: not the socket this daemon made any more; not removing it", path)
        return
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
