"""Recording (SPEC §12): what writing MCAP costs the recorder, and the file it makes.

    .venv/bin/python bench/recording.py [--drones 10] [--seconds 600]

Writes `drones` × 10 Hz telemetry (a real Telemetry payload, as agents publish it)
for `seconds` of log time through the same Recorder the ground and `fleet record` use
(zstd chunks closed every second), then reads the file back. Prints the CPU cost per
message, the bytes per message on disk against the payload size, the size of one
drone-hour, and the read-back rate.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.verdict import ScenarioFailed  # noqa: E402
from dronefleet.bus.recording import Recorder, read  # noqa: E402
from dronefleet.schemas.codec import encode  # noqa: E402
from dronefleet.schemas.telemetry import Battery, GpsInfo, Home, Position, Telemetry, VelocityNed  # noqa: E402


def payload(drone: int, i: int) -> bytes:
    return encode(Telemetry(
        drone_id=f"drone{drone:02d}", timestamp=1_700_000_000_000 + i * 100, seq=i, armed=True,
        battery=Battery(remaining_percent=round(1 - i * 1e-5, 4), voltage=16.2), flight_mode="mission",
        gps_info=GpsInfo(satellites=12, fix_type="fix_3d"), heading=(i * 0.7) % 360,
        home=Home(lat=40.6334, lon=-8.660815, alt=8.2), landed_state="in_air",
        position=Position(lat=40.6334 + i * 1e-7 + drone * 1e-4, lon=-8.660815 + i * 1e-7, alt=18.2 + (i % 50) * 0.01,
                          rel_alt=10.0 + (i % 50) * 0.01),
        velocity=VelocityNed(north=1.2, east=0.4, down=0.0), speed=1.26))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--drones", type=int, default=10)
    parser.add_argument("--seconds", type=int, default=600)
    args = parser.parse_args()
    ticks = args.seconds * 10
    payloads = [[payload(d, i) for d in range(args.drones)] for i in range(min(ticks, 500))]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        recorder = Recorder(path)
        t0 = 1_700_000_000_000_000_000
        raw = 0
        started = time.process_time()
        for i in range(ticks):
            for d, body in enumerate(payloads[i % len(payloads)]):
                recorder.write(f"drone/drone{d:02d}/telem", body, t0 + i * 100_000_000)
                raw += len(body)
        recorder.close()
        cpu = time.process_time() - started
        messages = ticks * args.drones
        size = path.stat().st_size
        started = time.perf_counter()
        contents = read(path)
        read_s = time.perf_counter() - started
        if len(contents.messages) != messages or not contents.complete:
            raise ScenarioFailed(f"read back {len(contents.messages)} of {messages} messages"
                                 f"{'' if contents.complete else ' from an incomplete file'}")
    print(f"{messages} telemetry messages ({args.drones} drones x 10 Hz x {args.seconds} s of log time)")
    print(f"write: {cpu / messages * 1e6:.1f} us CPU per message ({messages / cpu:,.0f} msg/s on one core)")
    print(f"file: {size / messages:.1f} bytes per message on disk for {raw / messages:.0f}-byte payloads "
          f"(zstd chunks of 1 s: x{raw / size:.1f}); one drone-hour at 10 Hz = {size / messages * 36_000 / 1e6:.1f} MB")
    print(f"read back: {messages / read_s:,.0f} msg/s")


if __name__ == "__main__":
    main()
