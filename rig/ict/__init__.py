"""The ICT Face Model light (real light-stage scans, MIT) in jnr: the project's compact copy
(:mod:`rig.ict.data`) and its dense correspondence with the template's topology (:mod:`rig.ict.transfer`)."""
