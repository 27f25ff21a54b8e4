"""Reports for people: calibration and noise figures (matplotlib Agg) and one HTML page.

``figures`` draws (pure: data in, matplotlib figures out), ``html`` embeds them as base64
PNG in a self-contained page (no network), ``cli`` holds the ``report`` and ``noise``
subcommands.
"""
