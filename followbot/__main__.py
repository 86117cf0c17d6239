from followbot.cli import main

raise SystemExit(main())
