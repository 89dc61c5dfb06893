#!/usr/bin/env python3
"""Independent reference read of an MCAP file for tests/read.rs.

Decodes messages with the official `mcap` + `mcap-ros2-support` Python packages and prints, as
JSON, the requested fields of the messages at the requested per-topic indices:

    dump_mcap.py FILE TOPIC INDEX[,INDEX...] FIELD [FIELD...]

Output: [{"index": i, "log_time": ns, "values": {FIELD: number, ...}}, ...]
Exit status 3 when the Python packages are missing (the test then skips).
"""
import json
import re
import sys

try:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
except ImportError as exc:  # the Rust test skips on this
    print(f"missing python package: {exc}", file=sys.stderr)
    sys.exit(3)


def lookup(msg, path):
    value = msg
    for part in path.split("."):
        m = re.fullmatch(r"(\w+)(?:\[(\d+)\])?", part)
        value = getattr(value, m.group(1))
        if m.group(2) is not None:
            value = value[int(m.group(2))]
    return float(value)


def main():
    path, topic, indices, fields = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
    wanted = sorted(int(i) for i in indices.split(","))
    out = []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for i, (_schema, _channel, message, decoded) in enumerate(
            reader.iter_decoded_messages(topics=[topic], log_time_order=True)
        ):
            if i in wanted:
                values = {field: lookup(decoded, field) for field in fields}
                out.append({"index": i, "log_time": message.log_time, "values": values})
            if i >= wanted[-1]:
                break
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
