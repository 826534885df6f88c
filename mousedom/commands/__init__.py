"""One module per ``mousedom`` subcommand, each a thin layer over the packages below."""
