from scantex.cli import main

raise SystemExit(main())
