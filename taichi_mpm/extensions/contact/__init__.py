"""Contact between bodies by a method of its own, the config's `contact:` section (docs/contact.md): multi_field,
one velocity field per body or group of bodies (`multifield.MultiField`, a step extension); its node fields are
declared in `fields.ContactNeeds` (layout.main_grid places them, budget.py counts them). Only created when the
config has a contact section: a scene without one allocates and compiles nothing here."""

from .fields import ContactNeeds
from .multifield import MultiField

__all__ = ["ContactNeeds", "MultiField"]
