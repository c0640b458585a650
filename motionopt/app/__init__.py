"""The application wing: the command line, batch runs and the demo. The only code that
imports ``priors`` and ``problems``; the engine below never imports it."""
