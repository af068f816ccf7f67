"""``python -m attitude_sil.cli``: the ``attitude-sil`` command."""

from attitude_sil.cli import main

raise SystemExit(main())
