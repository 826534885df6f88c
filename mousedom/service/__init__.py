"""The daemon and what only it uses: the loop, sensor slots, publishing, client commands,
reload, the Unix-socket server and protocol, sd_notify, live recording."""
