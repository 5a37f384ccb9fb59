"""The product: what ships, defined once in `product.yaml` beside this file.

The launcher's profiles take their argument defaults from it (`{product: KEY}`), the closed-loop benchmark judges it
(msfsu_evaluation.closed_loop.cli: a network drives as the product unless named with --network-only), and the demo, the
soak and the README's headline read it too; tests/test_product.py holds them together.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

PRODUCT_FILE = Path(__file__).with_name("product.yaml")


@dataclass(frozen=True)
class Product:
    checkpoint: Path  # the shipped network
    backend: str = "auto"  # perception's `backend`
    precision: str = "auto"  # perception's `precision`
    aeb: bool = True  # the emergency brake between perception and control
    aeb_parameters: dict[str, Any] = field(default_factory=dict)  # beyond the aeb node's defaults

    def value(self, key: str) -> Any:
        """A field as a profile argument takes it (the checkpoint as text)."""
        if key not in self.__dataclass_fields__:
            raise KeyError(f"the product has no '{key}' ({', '.join(self.__dataclass_fields__)})")
        value = getattr(self, key)
        return str(value) if isinstance(value, Path) else value


def load_product(path: Path = PRODUCT_FILE) -> Product:
    """ValueError with the reason when the file is not a product definition."""
    try:
        fields = yaml.safe_load(path.read_text()) or {}
        product = Product(**{**fields, "checkpoint": Path(fields["checkpoint"])})
    except (OSError, yaml.YAMLError, KeyError, TypeError) as error:
        raise ValueError(f"{path} is not a product definition: {error}") from None
    if not isinstance(product.aeb, bool) or not isinstance(product.aeb_parameters, dict):
        raise ValueError(f"{path}: aeb must be true or false and aeb_parameters a mapping")
    return product


def main() -> None:
    """`python -m msfsu_bringup.product KEY`: print one field (the Makefile's and scripts' default checkpoint)."""
    import sys

    print(load_product().value(sys.argv[1]))


if __name__ == "__main__":
    main()
