"""Pictures and reports: ``render`` (:mod:`.render`), ``render-tiles`` (:mod:`.render_tiles`),
matplotlib figures (:mod:`.plots`) and the self-contained HTML reports of the jobs (:mod:`.report`).

Views read files and stores; they never write results back.
"""
