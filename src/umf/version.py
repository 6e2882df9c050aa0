"""The package version, on its own so that any layer can name it without importing the
package's front door (:mod:`umf` lazily imports the pipeline)."""

__version__ = "0.1.0"
