"""What the test suite shares besides its fixtures: pytest plugins (``jax_setup``, ``xdist_queue``,
``worker_exit``, loaded by conftest.py's ``pytest_plugins``) and helpers (``paths``, ``notebooks``)."""
