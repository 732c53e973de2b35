"""The viewer process (a passive Zenoh subscriber) and its rerun sink. The defaults its flags
share with run_fleet.py are defined here, so that reading them loads nothing else."""

#: Default loopback ports of the web viewer (HTTP) and of the rerun gRPC server.
DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876
