"""Rewrite an MCAP file's messages in another storage layout with the `mcap` library (an
independent writer): `--order time` interleaves the topics by log time, `--order topic` writes
one topic after another; `--chunk-size 0` writes no chunks; `--index` adds the summary (chunk
and message indexes, statistics), otherwise there is none. Used by tests/read_index_trust.rs.

    python3 tests/py/mcap_layouts.py IN OUT --order topic --chunk-size 65536
"""

import argparse

from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--order", choices=["time", "topic"], required=True)
    ap.add_argument("--chunk-size", type=int, default=1 << 20)
    ap.add_argument("--index", action="store_true")
    a = ap.parse_args()

    with open(a.input, "rb") as f:
        msgs = [
            (ch.topic, sc.name, sc.encoding, sc.data, ch.message_encoding, m.log_time, m.publish_time, m.data)
            for sc, ch, m in make_reader(f).iter_messages(log_time_order=False)
        ]
    if a.order == "time":
        msgs.sort(key=lambda m: m[5])
    else:
        # Reverse topic order puts the power topics (which start later) before the joint states.
        msgs.sort(key=lambda m: (tuple(-ord(c) for c in m[0]), m[5]))

    with open(a.output, "wb") as out:
        w = Writer(
            out,
            chunk_size=max(a.chunk_size, 1),
            compression=CompressionType.ZSTD,
            index_types=IndexType.ALL if a.index else IndexType.NONE,
            use_chunking=a.chunk_size > 0,
            use_statistics=a.index,
            use_summary_offsets=a.index,
            repeat_channels=a.index,
            repeat_schemas=a.index,
        )
        w.start()
        channels = {}
        for seq, (topic, sname, senc, sdata, menc, log, pub, data) in enumerate(msgs):
            if topic not in channels:
                sid = w.register_schema(sname, senc, sdata)
                channels[topic] = w.register_channel(topic, menc, sid)
            w.add_message(channels[topic], log, data, pub, sequence=seq)
        w.finish()


if __name__ == "__main__":
    main()
