"""Image -> people -> per-track observations for trustnav.trust. Never imports trustnav.control.

So far: the LOOKING eye-contact model in numpy (``trustnav.perception.looking``).
"""
