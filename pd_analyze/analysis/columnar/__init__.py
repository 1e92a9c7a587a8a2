"""The columnar report path: a capture analysed a batch of frames at a time, as columns.

Each batch is decoded by numpy (`protocol.pnio_batch`, `protocol.profidrive_batch`). Frames are grouped
by the pair of IP addresses they travel between (a controller and a device: every call, channel and
fragment of a parameter access stays inside its pair). A group whose traffic is ordinary is analysed
here: calls paired by activity and sequence number over the whole batch, transactions formed by a small
state machine over the calls, tables built as columns. A group with anything unusual in it (fragments,
retransmissions, orphans, unanswered calls, malformed records, reads without a write...) goes to the
per-frame dissector and transaction engine, which stay the reference, from that batch on; what the
columns had learnt of the group (open calls, pending transactions, the channels' last transactions) is
handed over to them first. Both parts number transactions and remember read values in one frame order,
so the tables are those of the per-frame path (tests/test_columnar.py compares them).
"""
