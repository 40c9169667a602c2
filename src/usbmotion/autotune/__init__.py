"""Automatic tuning: identify an axis's model, place its loop from it, and check both.

``model`` fits the axis as its drive sees it (pure), ``loop`` picks gains from a model and
states the loop's margins and predicted responses (pure), ``identify`` and ``verify`` run
the tests on a connected machine.
"""
