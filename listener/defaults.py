"""Default network endpoints shared by the listener, the mock OBCU, the simulator and replay."""

DEFAULT_LISTENER_PORT = 48000  #: UDP port the listener receives INPUT_PROTOCOL on
DEFAULT_OBCU_PORT = 48001  #: UDP port the (mock) OBCU receives OUTPUT_PROTOCOL on
DEFAULT_HOST = "127.0.0.1"  #: loopback: the default for every test and the demo
