"""Use cases shared by the adapters: the node, the command line and the fleet call these."""
