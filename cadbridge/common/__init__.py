"""What every layer shares: atomic writes, the two error kinds, progress, the compile notice."""
