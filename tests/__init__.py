"""The test suite, one folder per cadbridge package (tests/<package>/ tests cadbridge/<package>/).

Every folder is a package so that pytest (default "prepend" import mode) imports each test
module under its dotted name, e.g. ``tests.iges.test_trims`` beside ``tests.cad.test_trims``;
shared test code is imported from ``tests.helpers``.
"""
