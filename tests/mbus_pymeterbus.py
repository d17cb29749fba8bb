#!/usr/bin/env python3
"""An M-Bus implementation from another project (pymeterbus, PyPI, BSD-3) for
tests/integration/mbus_pymeterbus.rs: builds the master's frames and decodes answers, and
prints what it made as one JSON object on stdout.

  mbus_pymeterbus.py frames                    the frames it builds (hex)
  mbus_pymeterbus.py decode FILE.hex...        each frame's records, or the error it gives
"""
import json
import sys

import meterbus


class Capture:
    """A serial port that keeps what pymeterbus writes to it."""

    def __init__(self):
        self.out = []

    def write(self, data):
        self.out.append(bytes(data).hex(" "))

    def read(self, _n):
        return b""


def frames():
    built = {}
    for address in (0, 1, 5, 250, 253):
        port = Capture()
        meterbus.send_ping_frame(port, address)
        meterbus.send_request_frame(port, address)
        meterbus.send_request_frame_multi(port, address)
        built[f"snd_nke {address}"] = port.out[0]
        built[f"req_ud2 {address}"] = port.out[1]
        built[f"req_ud2 fcb {address}"] = port.out[2]
    for mask in ("14491001FFFFFFFF", "1FFFFFFFFFFFFFFF", "FFFFFFFFFFFFFFFF",
                 "123456782D2C0104", "12F4F6F8FFFF07FF"):
        port = Capture()
        meterbus.send_select_frame(port, mask)
        built[f"select {mask}"] = port.out[0]
    return built


def decode(paths):
    out = {}
    for path in paths:
        data = bytes.fromhex(open(path).read())
        try:
            telegram = json.loads(meterbus.load(data).to_JSON())
        except Exception as e:  # noqa: BLE001 - the error is the answer
            out[path] = {"error": f"{type(e).__name__}: {e}"}
            continue
        out[path] = {
            "records": [
                {"unit": r.get("unit"), "type": r.get("type"), "value": r.get("value")}
                for r in telegram["body"]["records"]
            ]
        }
    return out


def main():
    if sys.argv[1] == "frames":
        print(json.dumps(frames()))
    else:
        print(json.dumps(decode(sys.argv[2:]), default=str))


if __name__ == "__main__":
    main()
