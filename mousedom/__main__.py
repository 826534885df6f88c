from mousedom.cli import main

raise SystemExit(main())
