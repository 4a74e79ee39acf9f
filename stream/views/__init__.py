"""Pictures and reports: ``render`` (:mod:`.render`), ``render-tiles`` (:mod:`.render_tiles`),
matplotlib figures (:mod:`.plots`), the pixel layout of a picture (:mod:`.layout`), axis names and units
from a CRS (:mod:`.units`) and the self-contained HTML reports of the jobs (:mod:`.report`).

Views read files and stores; they never write results back.
"""
