"""The ground floor everything stands on: the core contracts (``core``), the replay server and its
client (``replay``), the weight broadcast (``weights``), metrics and the fork server.

``__version__`` is graft's one version number: the package metadata (pyproject.toml reads it
here), ``graft --version`` and ``graft.__version__`` all give it."""

__version__ = "0.1.0"
