"""Tests of avdata.generators."""
