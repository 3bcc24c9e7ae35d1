"""The ``sonar`` sensor (`sonar`) and its beam patterns (`beam`)."""
