"""The emulated field network: real packets between Linux network namespaces, lost
as the radio model says (SPEC §8).

One `RadioNet` owns everything a run creates, all named after the run (the pid of
the process that made it) so a killed run's leftovers are recognised and removed
at the next start:
- an "air" namespace `fleet-<run>-air` holding a bridge, the shared medium;
- one namespace per drone, `fleet-<run>-<drone id>`, with an interface `radio0` on
  the bridge (its agent and on-board programs run there);
- a veth `fl<run>g` from the namespace it was made in (the laptop) to the bridge,
  which gets the ground's radio address.
Loss is applied in the air namespace by one nftables table (bridge family, forward
hook): for each ordered pair of nodes' bridge ports a rule `iifname A oifname B numgen
random mod 1000 < k drop` (by port, so multicast scouting and ARP fade too), the whole chain replaced in one atomic `nft -f` transaction at each
update. Rate is shaped with `tbf` where the model asks for it; delay needs `netem`,
which these kernels lack, and is applied only where `tc` accepts it. Every address
lives inside namespaces the run made; nothing is routed off the machine.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import ipaddress
import logging
import os
import re
import shutil
import signal
import socket
import subprocess
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping

from dronefleet.schemas.errors import FleetError
from dronefleet.sim.radio import GROUND, LOSS_STEPS, RadioModel

log = logging.getLogger(__name__)
NETNS_PREFIX = "fleet-"
_NETNS_RE = re.compile(r"^fleet-(\d+)-")
_LINK_RE = re.compile(r"^fl(\d+)g(@\S+)?$")
CAP_NET_ADMIN = 12
CLONE_NEWNET = 0x40000000
PR_SET_PDEATHSIG = 1
SUBNET_BASE = ipaddress.ip_network("10.231.0.0/16")  # one /24 per run, inside namespaces only
HOST_LOCK = "/run/fleet-radio.lock"  # root's tmpfs: radio runs need root anyway
TABLE = "fleet_radio"


class RadioUnavailable(FleetError):
    """The emulated network cannot be built here (no CAP_NET_ADMIN, no ip/nft)."""

    exit_code = 2


def has_net_admin() -> bool:
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> CAP_NET_ADMIN & 1)
    except OSError:
        pass
    return False


def require_net_admin() -> None:
    if not has_net_admin():
        raise RadioUnavailable(
            "the emulated radio needs CAP_NET_ADMIN to create network namespaces: run as root "
            "(or with `sudo`, or in a container started with --cap-add NET_ADMIN)"
        )
    missing = [tool for tool in ("ip", "nft", "tc") if shutil.which(tool) is None]
    if missing:
        raise RadioUnavailable(
            f"the emulated radio needs {', '.join(missing)}: install iproute2 and nftables "
            "(`apt-get install iproute2 nftables`; `make test` does this as root)"
        )


def _run(*args: str, stdin: str | None = None, check: bool = True) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(args, input=stdin, capture_output=True, text=True)
    if check and result.returncode != 0:
        raise RadioUnavailable(f"`{' '.join(args)}` failed: {result.stderr.strip() or result.returncode}")
    return result


def pid_alive(pid: int) -> bool:
    """Whether a process of this id runs (someone else's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def list_netns() -> list[str]:
    out = _run("ip", "netns", "list", check=False).stdout
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def leftovers(alive: Callable[[int], bool] = pid_alive) -> tuple[list[str], list[str]]:
    """Namespaces and laptop-side links of Fleet runs whose process is gone."""
    namespaces = [ns for ns in list_netns() if (m := _NETNS_RE.match(ns)) and not alive(int(m.group(1)))]
    links = []
    for line in _run("ip", "-o", "link", "show", check=False).stdout.splitlines():
        parts = line.split(": ")
        if len(parts) > 1 and (m := _LINK_RE.match(parts[1])) and not alive(int(m.group(1))):
            links.append(parts[1].split("@")[0])
    return namespaces, links


def remove_leftovers() -> list[str]:
    """Remove what killed runs left behind; returns what was removed."""
    namespaces, links = leftovers()
    for ns in namespaces:
        # Programs still inside (agents of a killed run) would keep the namespace alive.
        for pid in _run("ip", "netns", "pids", ns, check=False).stdout.split():
            with contextlib.suppress(ProcessLookupError, ValueError):
                os.kill(int(pid), signal.SIGKILL)
        _run("ip", "netns", "del", ns, check=False)
    for link in links:
        _run("ip", "link", "del", link, check=False)
    if namespaces or links:
        log.warning("removed leftovers of killed radio runs: %s", ", ".join(namespaces + links))
    return namespaces + links


@contextlib.contextmanager
def host_lock() -> Iterator[None]:
    """Radio runs started together (parallel tests, two operators) change the laptop's
    shared state one at a time: removing what killed runs left, and picking a free /24
    (held until its first address is on the laptop link, so no two pick the same)."""
    with open(HOST_LOCK, "a") as fd:
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)


def _pick_subnet() -> ipaddress.IPv4Network:
    used = _run("ip", "-o", "-4", "addr", "show", check=False).stdout
    for subnet in SUBNET_BASE.subnets(new_prefix=24):
        if f" {subnet.network_address + 1}/" not in used:
            return ipaddress.IPv4Network(subnet)
    raise RadioUnavailable(f"no free /24 left in {SUBNET_BASE} for the emulated radio")


def netem_available(dev: str, netns: str) -> bool:
    """Whether this kernel has sch_netem (probed once on a link of ours)."""
    probe = _run("ip", "netns", "exec", netns, "tc", "qdisc", "add", "dev", dev, "root", "netem", "delay", "1ms", check=False)
    if probe.returncode == 0:
        _run("ip", "netns", "exec", netns, "tc", "qdisc", "del", "dev", dev, "root", check=False)
        return True
    return False


class RadioNet:
    """The namespaces, links and loss rules of one run; `close()` removes them all."""

    def __init__(self, drone_ids: Iterable[str], model: RadioModel, *, run: int | None = None) -> None:
        self.drone_ids = list(drone_ids)
        self.model = model
        self.run = run if run is not None else os.getpid()
        self.air = f"{NETNS_PREFIX}{self.run}-air"
        self.laptop_link = f"fl{self.run}g"
        self.subnet = SUBNET_BASE  # set by up()
        self._addresses: dict[str, str] = {}
        self._ports: dict[str, str] = {}  # node -> its veth end in the air namespace
        self._applied: dict[tuple[str, str], int] = {}
        self._rates: dict[str, int] = {}
        self.netem = False
        self._made: list[Callable[[], object]] = []  # undo steps, newest last

    def netns(self, drone_id: str) -> str:
        return f"{NETNS_PREFIX}{self.run}-{drone_id}"

    def address(self, node: str) -> str:
        """The radio address of a drone or of the ground (`GROUND`)."""
        return self._addresses[node]

    @property
    def ground_address(self) -> str:
        return self._addresses[GROUND]

    def up(self) -> RadioNet:
        require_net_admin()
        with host_lock():
            remove_leftovers()
        try:
            self._add_netns(self.air)
            self._air("ip", "link", "add", "br0", "type", "bridge")
            self._air("ip", "link", "set", "br0", "up")
            # The laptop: a veth from here to the bridge, carrying the ground's address.
            _run("ip", "link", "add", self.laptop_link, "type", "veth", "peer", "name", "g", "netns", self.air)
            self._made.append(lambda: _run("ip", "link", "del", self.laptop_link, check=False))
            # No IPv6 link-local address on it: one address fewer appearing on the laptop,
            # where browsers abort requests in flight at each (Chromium's ERR_NETWORK_CHANGED).
            with contextlib.suppress(FileNotFoundError):
                with open(f"/proc/sys/net/ipv6/conf/{self.laptop_link}/disable_ipv6", "w") as ipv6:
                    ipv6.write("1")
            with host_lock():
                self.subnet = _pick_subnet()
                hosts = self.subnet.hosts()
                self._addresses[GROUND] = str(next(hosts))
                _run("ip", "addr", "add", f"{self._addresses[GROUND]}/24", "dev", self.laptop_link)
            _run("ip", "link", "set", self.laptop_link, "up")
            self._attach("g", GROUND)
            for i, drone_id in enumerate(self.drone_ids):
                ns = self.netns(drone_id)
                self._add_netns(ns)
                self._addresses[drone_id] = str(next(hosts))
                port = f"d{i}"
                _run("ip", "link", "add", "radio0", "netns", ns, "type", "veth", "peer", "name", port, "netns", self.air)
                _run("ip", "-n", ns, "addr", "add", f"{self._addresses[drone_id]}/24", "dev", "radio0")
                _run("ip", "-n", ns, "link", "set", "radio0", "up")
                _run("ip", "-n", ns, "link", "set", "lo", "up")
                self._attach(port, drone_id)
            self._air("nft", "-f", "-", stdin=(
                f"table bridge {TABLE} {{\n"
                f"  chain radio {{ type filter hook forward priority 0; policy accept; }}\n"
                f"}}\n"
            ))
            self.netem = netem_available(self._ports[GROUND], self.air)
        except BaseException:
            self.close()
            raise
        log.info("radio: %s on %s (ground %s), netem %s", ", ".join(self.drone_ids), self.subnet,
                 self.ground_address, "yes" if self.netem else "no (loss and rate only)")
        return self

    def _add_netns(self, name: str) -> None:
        _run("ip", "netns", "add", name)
        self._made.append(lambda: _run("ip", "netns", "del", name, check=False))

    def _air(self, *args: str, stdin: str | None = None) -> None:
        _run("ip", "netns", "exec", self.air, *args, stdin=stdin)

    def _attach(self, port: str, node: str) -> None:
        self._air("ip", "link", "set", port, "master", "br0")
        self._air("ip", "link", "set", port, "up")
        self._ports[node] = port

    def apply(self, losses: Mapping[tuple[str, str], int]) -> bool:
        """Set the loss (1/1000ths) of every pair of nodes; pairs not named lose nothing.

        One atomic nftables transaction; skipped when nothing changed. Returns whether
        the rules were rewritten."""
        wanted = {pair: k for pair, k in losses.items() if k > 0}
        if wanted == self._applied:
            return False
        lines = [f"flush chain bridge {TABLE} radio"]
        for (a, b), k in sorted(wanted.items()):
            for src, dst in ((a, b), (b, a)):
                match = f'iifname "{self._ports[src]}" oifname "{self._ports[dst]}"'
                verdict = "drop" if k >= LOSS_STEPS else f"numgen random mod {LOSS_STEPS} < {k} drop"
                lines.append(f"add rule bridge {TABLE} radio {match} {verdict}")
        self._air("nft", "-f", "-", stdin="\n".join(lines) + "\n")
        self._applied = wanted
        return True

    def shape(self, node: str, distance_to_ground_m: float) -> None:
        """Rate (and delay, with netem) of the link towards `node`, from its distance."""
        rate = self.model.rate(distance_to_ground_m)
        if not rate and not self.netem:
            return
        previous = self._rates.get(node)
        if previous is not None and abs(previous - rate) <= 0.1 * max(previous, 1):
            return
        self._rates[node] = rate
        if self.netem:
            args = ["netem", "delay", f"{self.model.delay(distance_to_ground_m):.1f}ms"]
            args += ["rate", f"{rate}kbit"] if rate else []
        else:
            args = ["tbf", "rate", f"{rate}kbit", "burst", "32kbit", "latency", "200ms"]
        self._air("tc", "qdisc", "replace", "dev", self._ports[node], "root", *args)

    def exec_args(self, drone_id: str) -> list[str]:
        """Prefix that runs a command inside a drone's namespace."""
        return ["ip", "netns", "exec", self.netns(drone_id)]

    def close(self) -> None:
        while self._made:
            undo = self._made.pop()
            with contextlib.suppress(Exception):
                undo()

    def __enter__(self) -> RadioNet:
        return self.up()

    def __exit__(self, *exc: object) -> None:
        self.close()


def die_with_parent() -> None:
    """preexec_fn for children of a radio run: SIGTERM them if the launcher dies
    (kept across `ip netns exec`'s exec), so a killed run leaves no agents behind."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def socket_in_netns(netns: str, family: int = socket.AF_INET, kind: int = socket.SOCK_DGRAM) -> socket.socket:
    """A socket created inside another network namespace (it stays there for life).

    setns() moves only the calling thread, so a short-lived thread makes it: the
    vehicle simulator keeps running here while its MAVLink socket lives on the drone."""
    result: list[socket.socket | BaseException] = []

    def make() -> None:
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            with open(f"/run/netns/{netns}") as fd:
                if libc.setns(fd.fileno(), CLONE_NEWNET) != 0:
                    raise OSError(ctypes.get_errno(), f"setns into {netns} failed")
            result.append(socket.socket(family, kind))
        except BaseException as exc:  # handed to the caller's thread
            result.append(exc)

    thread = threading.Thread(target=make, name=f"setns {netns}")
    thread.start()
    thread.join()
    made = result[0]
    if isinstance(made, BaseException):
        raise made
    return made
