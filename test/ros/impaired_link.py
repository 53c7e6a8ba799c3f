"""Test infrastructure: two network namespaces joined by a userspace link with a fixed delay and seeded random loss.

The kernel's netem qdisc is not available everywhere (``sch_netem`` is a module), so the link is a
TAP device in each namespace and a thread of the test process that forwards every Ethernet frame
read from one TAP to the other after ``delay_s``, dropping each with probability ``loss``
(``random.Random(seed)``, one generator per direction). Frames are never reordered: one FIFO per
direction, all delayed alike. The namespaces hold only ``lo`` and their TAP (``10.231.<n>.1`` and
``.2``/24, a multicast route on the TAP for DDS discovery), so nothing they send reaches any other
network. The TAP devices are created in this namespace (``/dev/net/tun``) and moved into theirs; they
vanish when the forwarder closes them. Needs root and ``ip`` (iproute2).

    with ImpairedLink(("ground", "drone"), delay_s=0.05, loss=0.05, seed=1) as link:
        subprocess.run(link.exec("drone") + ["python", ...])
    link.stats  # {"ground->drone": {"frames": .., "dropped": ..}, "drone->ground": {...}}
"""

from __future__ import annotations

import collections
import fcntl
import os
import random
import selectors
import struct
import subprocess
import threading
import time

TUNSETIFF = 0x400454CA
"""ioctl of /dev/net/tun attaching the file to a device (linux/if_tun.h)."""
IFF_TAP, IFF_NO_PI = 0x0002, 0x1000


def _ip(*args: str) -> None:
    run = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)
    if run.returncode != 0:
        raise OSError(f"ip {' '.join(args)}: {run.stderr.strip()}")


class ImpairedLink:
    """Namespaces ``names`` (made unique with this pid: :meth:`namespace`) joined by the impaired link (module doc)."""

    def __init__(self, names: tuple[str, str], delay_s: float, loss: float, seed: int, subnet: int = 7):
        self.names, self.delay_s, self.loss, self.seed = names, delay_s, loss, seed
        self.prefix = f"10.231.{subnet}"
        self.fds: list[int] = []
        self.created: list[str] = []
        self.stats = {f"{a}->{b}": {"frames": 0, "dropped": 0} for a, b in (names, names[::-1])}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def namespace(self, name: str) -> str:
        return f"qm-{name}-{os.getpid()}"

    def address(self, name: str) -> str:
        return f"{self.prefix}.{self.names.index(name) + 1}"

    def exec(self, name: str) -> list[str]:
        """The command prefix running a program inside namespace ``name``."""
        return ["ip", "netns", "exec", self.namespace(name)]

    def __enter__(self) -> ImpairedLink:
        try:
            for name in self.names:
                ns, tap = self.namespace(name), f"qm{name[0]}{os.getpid()}"[:15]
                _ip("netns", "add", ns)
                self.created.append(ns)
                fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
                self.fds.append(fd)
                fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", tap.encode(), IFF_TAP | IFF_NO_PI))
                _ip("link", "set", tap, "netns", ns)
                _ip("-n", ns, "link", "set", "lo", "up")
                _ip("-n", ns, "addr", "add", f"{self.address(name)}/24", "dev", tap)
                _ip("-n", ns, "link", "set", tap, "up")
                _ip("-n", ns, "route", "add", "224.0.0.0/4", "dev", tap)
        except BaseException:
            self.__exit__()
            raise
        self._thread = threading.Thread(target=self._forward, name="impaired-link", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        for fd in self.fds:
            os.close(fd)  # the TAP devices go with their last file
        self.fds.clear()
        for ns in self.created:
            for pid in subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True).stdout.split():
                try:
                    os.kill(int(pid), 9)  # a process the test started in the namespace and could not stop
                except ProcessLookupError:
                    pass
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        self.created.clear()

    def _forward(self) -> None:
        """Read frames from either TAP; deliver each to the other after delay_s unless the direction's generator drops it."""
        (a, b), (fa, fb) = self.names, self.fds
        route = {fa: (fb, f"{a}->{b}", random.Random(self.seed)), fb: (fa, f"{b}->{a}", random.Random(self.seed + 1))}
        queues = {fa: collections.deque(), fb: collections.deque()}  # (due time [s], frame) per output, in order
        selector = selectors.DefaultSelector()
        for fd in route:
            selector.register(fd, selectors.EVENT_READ)
        while not self._stop.is_set():
            dues = [q[0][0] for q in queues.values() if q]
            wait = min(0.05, max(0.0, min(dues) - time.monotonic())) if dues else 0.05
            for key, _ in selector.select(wait):
                out, direction, rng = route[key.fd]
                while True:
                    try:
                        frame = os.read(key.fd, 65536)
                    except BlockingIOError:
                        break
                    self.stats[direction]["frames"] += 1
                    if rng.random() < self.loss:
                        self.stats[direction]["dropped"] += 1
                        continue
                    queues[out].append((time.monotonic() + self.delay_s, frame))
            now = time.monotonic()
            for out, queue in queues.items():
                while queue and queue[0][0] <= now:
                    try:
                        os.write(out, queue.popleft()[1])
                    except OSError:
                        pass  # the device is going down
        selector.close()
