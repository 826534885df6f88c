"""Devices -> reports: evdev mice (event decoding, discovery) and the ADNS-3080 downsampler
(framing, decoding, clock sync).  Hardware lives here; the service is not known here."""
