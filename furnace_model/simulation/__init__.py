"""The furnace and its model: the description (zones, burners, thermocouples, links), the
thermal network built from it, the exact batched simulator, the model structure with its
optional effect terms, and the plant simulator that sees it through real thermocouples.
"""
