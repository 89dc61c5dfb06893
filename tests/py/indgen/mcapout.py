"""MCAP output through mcap.writer.Writer, with a bulk path for pre-serialised message records.

mcap's Writer builds one Python object per message; at 3 M messages per session that dominates
the run time. `BulkWriter.add_chunk` hands the Writer one chunk's worth of complete Message
records (built in numpy, see cdr.Block) plus their per-channel (log_time, offset) index entries;
the Writer itself then compresses the chunk (zstd), writes the chunk record, the message index
records, and later the chunk indexes, statistics and summary exactly as for add_message.
"""
import struct

import numpy as np
import zstandard
from mcap import writer as _mw
from mcap.opcode import Opcode
from mcap.writer import CompressionType, IndexType, Writer


class _PackedIndex:
    """Stands in for mcap.records.MessageIndex: writes a precomputed entries buffer."""

    def __init__(self, channel_id, times, offsets):
        self.channel_id = channel_id
        ent = np.empty((len(times), 2), "<u8")
        ent[:, 0] = times
        ent[:, 1] = offsets
        self.entries = ent.tobytes()

    def write(self, stream):
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(self.entries))
        stream.write(self.entries)
        stream.finish_record()


class _Zstd:
    """zstandard.compress at a chosen level (mcap's Writer calls the module-level function)."""

    def __init__(self, level):
        self.c = zstandard.ZstdCompressor(level=level)

    def compress(self, data):
        return self.c.compress(data)


class BulkWriter(Writer):
    def __init__(self, stream, zstd_level=1):
        super().__init__(stream, chunk_size=1 << 62, compression=CompressionType.ZSTD,
                         index_types=IndexType.ALL)
        _mw.zstandard = _Zstd(zstd_level)

    def add_chunk(self, data, channels):
        """data: bytes of consecutive Message records; channels: {channel_id: (log_times, offsets)}
        with offsets relative to the start of `data`."""
        cb = self._Writer__chunk_builder
        assert cb.num_messages == 0
        base = cb.count  # schemas/channels registered before the first chunk live in it
        cb.record_writer.write(data)
        st = self._Writer__statistics
        tmin, tmax, n = None, None, 0
        for ch, (times, offs) in channels.items():
            if len(times) == 0:
                continue
            cb.message_indices[ch] = _PackedIndex(ch, times, np.asarray(offs, np.uint64) + np.uint64(base))
            t0, t1 = int(times.min()), int(times.max())
            tmin = t0 if tmin is None else min(tmin, t0)
            tmax = t1 if tmax is None else max(tmax, t1)
            n += len(times)
            st.channel_message_counts[ch] += len(times)
        if n == 0:
            return
        if st.message_count == 0:
            st.message_start_time = tmin
        else:
            st.message_start_time = min(st.message_start_time, tmin)
        st.message_end_time = max(st.message_end_time, tmax)
        st.message_count += n
        cb.num_messages = n
        cb.message_start_time = tmin
        cb.message_end_time = tmax
        self._Writer__finalize_chunk()
