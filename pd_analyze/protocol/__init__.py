"""The protocol layers, one module per layer, each layer's checks beside its parser.

link (Ethernet/VLAN/SLL -> IPv4 -> UDP), rpc (DCE/RPC CL), pnio (NDR args, IOD record headers,
Write-Multiple) with pnio_checks, profidrive (parameter requests and responses) with
profidrive_checks and the vendor profiles (profiles, profile_data/*.toml); dissector ties them
together frame by frame.
"""
