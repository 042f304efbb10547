"""Rules shared by the live and offline paths: marks, epochs and phase continuity.

Each module owns one rule and offers it in the forms its users need (a streaming form for the
monitor and the decoder, a batch or vectorised form for RINEX, inspect and the solver), so the
operator's live view and the files written afterwards cannot disagree.
"""
