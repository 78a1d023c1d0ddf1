"""A TCP proxy that adds latency: each chunk of bytes is forwarded ``delay ± jitter`` ms after it arrived, in order.

For testing racer over a slow network where the kernel has no ``netem`` qdisc (``deploy/cluster/check-hosts.sh``
runs one in each worker host's network namespace, in front of Redis and of the S3 server)::

    python deploy/cluster/delay_proxy.py --listen 127.0.0.1:6379 --target 10.231.0.1:6379 --delay-ms 50 --jitter-ms 10

Each direction of each connection is delayed on its own; a chunk never overtakes the one before it (its due time is
at least the previous chunk's), so the byte stream is unchanged. Bandwidth and loss are left to the kernel (``tc``,
``iptables``) on the real links behind it. The proxy stays as close as it can to what a client would see without
it: a clean end of stream is forwarded after the bytes before it (half-close), a reset aborts the other side, and a
target that cannot be reached within ``--connect-timeout`` (5 s, redis-py's and botocore's own connect timeout)
closes the client's connection.

SIGUSR1 turns the delay on, SIGUSR2 off (``--off`` starts with it off): a baseline and a shaped measurement go
through the same proxy. SIGTERM or SIGINT stops it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import random
import signal
import sys

CHUNK = 65536
QUEUED_CHUNKS = 64
"""Chunks read ahead of their due time per direction (backpressure beyond that: the reader waits)."""


class Delay:
    """The current delay: ``delay_s ± jitter_s``, uniform, or zero while off."""

    def __init__(self, delay_s: float, jitter_s: float, on: bool) -> None:
        self.delay_s, self.jitter_s, self.on = delay_s, jitter_s, on

    def sample(self) -> float:
        if not self.on:
            return 0.0
        return max(0.0, self.delay_s + random.uniform(-self.jitter_s, self.jitter_s))


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, delay: Delay, peer: asyncio.StreamWriter):
    """Forward ``reader`` → ``writer`` with delay; on a reset of either side, abort both (``peer`` is the writer of
    the side ``reader`` reads, aborted with it)."""
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[tuple[float, bytes | None]] = asyncio.Queue(QUEUED_CHUNKS)

    async def read() -> None:
        last_due = 0.0
        while True:
            try:
                chunk = await reader.read(CHUNK)
            except OSError:  # reset: as TCP would, reset the other side now, dropping what was not delivered
                writer.transport.abort()
                with contextlib.suppress(asyncio.QueueFull):  # wake the writer (a full queue fails it anyway)
                    queue.put_nowait((0.0, None))
                return
            due = max(loop.time() + delay.sample(), last_due)
            last_due = due
            await queue.put((due, chunk))
            if not chunk:
                return

    async def write() -> None:
        while True:
            due, chunk = await queue.get()
            wait = due - loop.time()
            if wait > 0:
                await asyncio.sleep(wait)
            if chunk is None:  # the source was reset (and this side aborted)
                return
            if not chunk:  # clean end of stream, after every byte before it
                if writer.can_write_eof():
                    writer.write_eof()
                return
            writer.write(chunk)
            await writer.drain()

    reading = asyncio.ensure_future(read())
    try:
        await write()
    except OSError:  # the destination went away: stop reading, reset the source
        peer.transport.abort()
    finally:
        reading.cancel()
        with contextlib.suppress(asyncio.CancelledError, OSError):
            await reading


class Proxy:
    """Listens on ``listen`` and forwards every connection to ``target`` through two delayed pumps."""

    def __init__(self, target: tuple[str, int], delay: Delay, connect_timeout_s: float) -> None:
        self.target, self.delay, self.connect_timeout_s = target, delay, connect_timeout_s
        self.connections = 0
        self.open: set[asyncio.Task] = set()

    async def handle(self, c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        task = asyncio.current_task()
        self.open.add(task)
        try:
            await self._forward(c_reader, c_writer)
        except asyncio.CancelledError:  # stopping: reset both sides
            c_writer.transport.abort()
        finally:
            self.open.discard(task)

    async def stop(self) -> None:
        """Reset every open connection."""
        for task in list(self.open):
            task.cancel()
        await asyncio.gather(*self.open, return_exceptions=True)

    async def _forward(self, c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        try:
            u_reader, u_writer = await asyncio.wait_for(
                asyncio.open_connection(*self.target), timeout=self.connect_timeout_s
            )
        except (OSError, TimeoutError):
            c_writer.transport.abort()  # the client sees a failed connection, as it would without the proxy
            return
        try:
            await asyncio.gather(
                _pump(c_reader, u_writer, self.delay, c_writer),
                _pump(u_reader, c_writer, self.delay, u_writer),
            )
        except asyncio.CancelledError:
            u_writer.transport.abort()
            raise
        finally:
            for w in (c_writer, u_writer):
                w.close()


def _address(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT")
    return host, int(port)


async def serve(args: argparse.Namespace) -> None:
    delay = Delay(args.delay_ms / 1000.0, args.jitter_ms / 1000.0, on=not args.off)
    proxy = Proxy(args.target, delay, args.connect_timeout)
    server = await asyncio.start_server(proxy.handle, *args.listen, reuse_address=True)
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()

    def switch(on: bool) -> None:
        delay.on = on
        print(f"delay {'on' if on else 'off'}", flush=True)

    loop.add_signal_handler(signal.SIGUSR1, switch, True)
    loop.add_signal_handler(signal.SIGUSR2, switch, False)
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    print(
        f"proxy {args.listen[0]}:{args.listen[1]} -> {args.target[0]}:{args.target[1]}, "
        f"delay {args.delay_ms:g} ± {args.jitter_ms:g} ms ({'off' if args.off else 'on'})",
        flush=True,
    )
    async with server:
        await stop.wait()
        server.close()
        await proxy.stop()
    print(f"proxy stopped after {proxy.connections} connections", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--listen", type=_address, required=True, help="HOST:PORT to listen on")
    parser.add_argument("--target", type=_address, required=True, help="HOST:PORT to forward to")
    parser.add_argument("--delay-ms", type=float, default=50.0, help="delay of each chunk, each direction")
    parser.add_argument("--jitter-ms", type=float, default=10.0, help="uniform ± around the delay")
    parser.add_argument("--connect-timeout", type=float, default=5.0, help="seconds to reach the target")
    parser.add_argument("--off", action="store_true", help="start with the delay off (SIGUSR1 turns it on)")
    args = parser.parse_args(argv)
    if args.jitter_ms > args.delay_ms or args.delay_ms < 0:
        parser.error("need 0 <= jitter <= delay")
    asyncio.run(serve(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
