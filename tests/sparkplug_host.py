#!/usr/bin/env python3
"""A Sparkplug B host for the integration tests, on pysparkplug (an implementation not written
here, on Eclipse Tahu's protobuf): subscribes to spBv1.0/# on the test's broker and prints one
JSON line per message, decoded the way a host decodes it (DDATA through the DBIRTH that
declared its aliases). Reads commands from stdin, one JSON line each:
  {"ncmd": "<group>/<node>", "rebirth": true}   (or "reboot", "next_server": node controls)
  {"dcmd": "<group>/<node>/<device>", "metric": "a0/Clear", "type": "BOOLEAN", "value": true}
  {"state": "<host>", "online": true}      (a primary host's retained STATE, spec 3.0;
                                            "timestamp": ms to send another than now)
  {"state_raw": "<host>", "payload": "..."} (any STATE payload, retained)
  {"...": ..., "count": N}                  (an ncmd or dcmd sent N times, back to back)
Usage: sparkplug_host.py <port> [persistent]   (persistent: a session the broker keeps)

A message the broker sends again (MQTT's DUP flag) that this host already took is printed as a
REDELIVERED line, not decoded again: QoS 1 is at least once, and a broker restarted with the
host's session resends what it had sent but not seen acknowledged before it stopped (the host
took it, its PUBACK came too late). Decoded twice, the node's seq would seem to go back (16, then
14 again) although the node sent each message once and in order.
"""

import collections
import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from pysparkplug import DataType, DBirth, DCmd, DData, Metric, NBirth, NCmd
from pysparkplug._protobuf import Payload as PBPayload

births = {}  # (group, node, device or None) -> Birth
out_lock = threading.Lock()
# The last messages taken, as (packet id, topic, payload): what a resend (DUP) repeats.
taken = collections.deque(maxlen=4096)


def emit(obj):
    with out_lock:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


def props(pb_metric):
    if not pb_metric.HasField("properties"):
        return {}
    p = pb_metric.properties
    return {k: v.string_value for k, v in zip(p.keys, p.values)}


def metric_json(m, pb_metric=None):
    return {
        "name": m.name,
        "alias": m.alias,
        "datatype": DataType(m.datatype).name,
        "value": m.value,
        "is_null": m.is_null,
        "is_historical": m.is_historical,
        "timestamp": m.timestamp,
        "properties": props(pb_metric) if pb_metric is not None else {},
    }


def decode(topic, raw):
    levels = topic.split("/")
    if levels[1] == "STATE":
        return {"topic": topic, "type": "STATE", "payload": raw.decode(errors="replace")}
    _, group, kind, node = levels[:4]
    device = levels[4] if len(levels) > 4 else None
    key = (group, node, device)
    line = {"topic": topic, "type": kind, "node": node, "device": device}
    pb = PBPayload.FromString(raw)
    line["seq"] = pb.seq if pb.HasField("seq") else None
    line["timestamp"] = pb.timestamp if pb.HasField("timestamp") else None
    if kind in ("NBIRTH", "DBIRTH"):
        cls = NBirth if kind == "NBIRTH" else DBirth
        birth = cls.decode(raw)
        births[key] = birth
        if kind == "NBIRTH":
            # A new node birth invalidates the births of its devices.
            for k in [k for k in births if k[:2] == (group, node) and k[2] is not None]:
                del births[k]
        line["metrics"] = [metric_json(m, p) for m, p in zip(birth.metrics, pb.metrics)]
    elif kind == "DDATA":
        birth = births.get(key)
        if birth is None:
            line["error"] = "DDATA before its DBIRTH"
            return line
        try:
            data = DData.decode(raw, birth=birth)
        except KeyError as e:
            line["error"] = f"alias {e} was not declared in the DBIRTH"
            return line
        line["metrics"] = [
            dict(metric_json(m), named_on_wire=p.HasField("name"))
            for m, p in zip(data.metrics, pb.metrics)
        ]
    else:  # NDEATH, DDEATH, NDATA
        line["metrics"] = [{"name": m.name, "value": raw_value(m)} for m in pb.metrics]
    return line


def raw_value(m):
    for field in ("long_value", "int_value", "string_value", "boolean_value", "double_value"):
        if m.HasField(field):
            return getattr(m, field)
    return None


def redelivered(msg):
    """The broker sends again (DUP) a message this host already took: the same packet id, topic
    and payload. A DUP message not taken before is a first delivery and is decoded."""
    key = (msg.mid, msg.topic, bytes(msg.payload))
    if msg.dup and key in taken:
        return True
    taken.append(key)
    return False


def on_message(client, userdata, msg):
    if redelivered(msg):
        emit({"topic": msg.topic, "type": "REDELIVERED", "mid": msg.mid})
        return
    try:
        emit(decode(msg.topic, msg.payload))
    except Exception as e:  # a payload this host cannot read is a finding, not a crash
        emit({"topic": msg.topic, "error": f"{type(e).__name__}: {e}"})


def on_connect(client, userdata, flags, rc):
    client.subscribe("spBv1.0/#", qos=1)


def command(client, line):
    cmd = json.loads(line)
    now = int(time.time() * 1000)
    count = cmd.get("count", 1)
    if "ncmd" in cmd:
        group, node = cmd["ncmd"].split("/")
        controls = {"rebirth": "Rebirth", "reboot": "Reboot", "next_server": "Next Server"}
        metrics = tuple(
            Metric(now, f"Node Control/{name}", DataType.BOOLEAN, value=True)
            for key, name in controls.items()
            if cmd.get(key)
        )
        payload = NCmd(now, metrics).encode(include_dtypes=True)
        for _ in range(count):
            client.publish(f"spBv1.0/{group}/NCMD/{node}", payload, qos=0)
    elif "dcmd" in cmd:
        group, node, device = cmd["dcmd"].split("/")
        dt = DataType[cmd.get("type", "BOOLEAN")]
        metric = Metric(now, cmd["metric"], dt, value=cmd["value"])
        payload = DCmd(now, (metric,)).encode(include_dtypes=True)
        for _ in range(count):
            client.publish(f"spBv1.0/{group}/DCMD/{node}/{device}", payload, qos=0)
    elif "state" in cmd:
        stamp = cmd.get("timestamp", now)
        body = json.dumps({"online": cmd["online"], "timestamp": stamp})
        client.publish(f"spBv1.0/STATE/{cmd['state']}", body, qos=1, retain=True)
    elif "state_raw" in cmd:
        client.publish(f"spBv1.0/STATE/{cmd['state_raw']}", cmd["payload"], qos=1, retain=True)
    emit({"type": "SENT", "command": cmd, "at": now})


def main():
    port = int(sys.argv[1])
    persistent = sys.argv[2:] == ["persistent"]
    client = mqtt.Client(client_id=f"sparkplug-host-{port}", clean_session=not persistent)
    client.on_connect = on_connect
    client.on_message = on_message
    while True:
        try:
            client.connect("127.0.0.1", port, keepalive=30)
            break
        except OSError:
            time.sleep(0.2)
    client.loop_start()
    while not client.is_connected():
        time.sleep(0.05)
    time.sleep(0.3)  # the SUBACK
    emit({"type": "READY"})
    for line in sys.stdin:
        if line.strip():
            command(client, line)
    client.loop_stop()


if __name__ == "__main__":
    main()
