#!/usr/bin/env python3
"""A PLC's side of the Modbus server output for the integration tests, on pymodbus (an
implementation not written here). Connects to 127.0.0.1:<port>, from <source> when given (a
loopback address such as 127.0.0.2, to test `allow`), and answers one JSON line per request
line on stdin:
  {"op": "read", "table": "input"|"holding", "unit": 3, "address": 20, "count": 4}
      -> {"registers": [...]} | {"exception": 2} | {"error": "..."}
  {"op": "reads", "unit": 3, "address": 20, "n": 1000, "pause": 0.001}
      -> {"totals": [...], "seconds": s}: n reads of the int64 at address (function 04, four
         registers, high word first), `pause` seconds apart (default none), as a PLC's fast
         task does
  {"op": "write", "unit": 3, "address": 32, "value": 1}               (function 06)
  {"op": "write_registers", "unit": 3, "address": 33, "values": [..]} (function 16)
      -> {"ok": true} | {"exception": 1} | {"error": "..."}
Usage: plc_clients.py <port> [source]
"""

import json
import sys
import time

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ModbusException


def int64(words):
    v = 0
    for w in words:
        v = (v << 16) | w
    return v - (1 << 64) if v >= 1 << 63 else v


def outcome(result, ok):
    if result.isError():
        code = getattr(result, "exception_code", None)
        if code is None:
            return {"error": str(result)}
        return {"exception": code}
    return ok(result)


def one(client, req):
    op, unit = req["op"], req.get("unit", 1)
    if op == "read":
        call = (
            client.read_holding_registers
            if req.get("table") == "holding"
            else client.read_input_registers
        )
        r = call(req["address"], count=req["count"], device_id=unit)
        return outcome(r, lambda r: {"registers": list(r.registers)})
    if op == "reads":
        totals, start = [], time.monotonic()
        for _ in range(req["n"]):
            r = client.read_input_registers(req["address"], count=4, device_id=unit)
            if r.isError():
                return {"error": str(r), "after": len(totals)}
            totals.append(int64(r.registers))
            if req.get("pause"):
                time.sleep(req["pause"])
        return {"totals": totals, "seconds": time.monotonic() - start}
    if op == "write":
        r = client.write_register(req["address"], req["value"], device_id=unit)
        return outcome(r, lambda r: {"ok": True})
    if op == "write_registers":
        r = client.write_registers(req["address"], req["values"], device_id=unit)
        return outcome(r, lambda r: {"ok": True})
    return {"error": f"unknown op {op}"}


def main():
    port = int(sys.argv[1])
    source = (sys.argv[2], 0) if len(sys.argv) > 2 else None
    # No retries: a refused or closed connection must show, not be hidden by a second try.
    client = ModbusTcpClient(
        "127.0.0.1", port=port, source_address=source, timeout=12, retries=0
    )
    connected = client.connect()
    print(json.dumps({"connected": bool(connected)}), flush=True)
    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            answer = one(client, json.loads(line))
        except (ModbusException, ValueError, OSError) as e:
            answer = {"error": f"{type(e).__name__}: {e}"}
        print(json.dumps(answer), flush=True)
    client.close()


if __name__ == "__main__":
    main()
