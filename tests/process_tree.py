"""The processes of a run, read from /proc: what the signal and shutdown tests check is left behind."""

from pathlib import Path


def children_of(pids: set) -> set:
    """The processes whose parent is one of ``pids``."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) in pids:
                    found.add(int(entry.name))
            except (OSError, IndexError, ValueError):
                pass
    return found


def descendants(pid: int) -> set:
    """Every process below ``pid``: its children, theirs, and so on."""
    found, frontier = set(), {pid}
    while frontier:
        frontier = children_of(frontier) - found
        found |= frontier
    return found


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (exists and is not a zombie)."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def cmdline(pid: int) -> str:
    """``pid``'s command line ('' once it is gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def pool_workers(main_pid: int) -> list:
    """The seed workers of the run in process ``main_pid``: its spawned children, or the children of its fork server
    (imix_cli.core.processes.start_seed_worker_server), whose command line is the server's."""
    kids = children_of({main_pid})
    servers = {p for p in kids if "multiprocessing.forkserver" in cmdline(p)}
    return sorted(p for p in kids | children_of(servers) if "spawn_main" in cmdline(p) or (p not in servers and "multiprocessing.forkserver" in cmdline(p)))
